"""The renderer: physics for one pixel (`shade`), batched over an image by `vmap`, jitted.

Layout, measured on a 2-core CPU: geometry goes in as one array per component (`Vec3` of
(H, W) arrays, so XLA vectorises along pixels; (H, W, 3) inputs batch into (pixels, 3)
arrays and ran 6-7x slower in a prototype). `render` runs as two programs, each one fused
loop: the per-pixel lobe columns in one pass over the geometry, then the image (H, W, 3)
from them (see `render` for why).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ._camera import Camera
from ._convert import cast_floating
from ._errors import ParameterError
from ._numerics import safe_normalize
from ._typing import RGB, Array, Float, Pixel, Scalar
from ._vector import Vec3, where
from .effects import AbstractImageEffect
from .effects._effect import Site, apply_effects
from .lights import AbstractLight
from .lobes import BRDF

__all__ = ["Site", "apply_effects", "render", "render_columns", "shade", "shade_columns"]


def shade_columns(
    brdf: BRDF,
    light: AbstractLight,
    point: Vec3,
    normal: Vec3,
    pixel: Pixel,
    eye: Vec3 | None = None,
) -> Float[Array, " K"]:
    """One pixel's radiance per lobe for unit weights: the linear design-matrix row.

    `point` is the surface point and `normal` its unit normal, camera frame (mm); `eye`
    as in `shade`.
    """
    return jnp.stack(_lobe_radiances(brdf, light, point, normal, pixel, eye))


def _directions(point: Vec3, eye: Vec3 | None) -> tuple[Vec3, Vec3]:
    """The unit directions from `point` to the lens the light is mounted on (the frame's
    origin: what the light is given) and to the viewer (the same vector object where the
    viewer is that lens, so that lobes know L = V exactly)."""
    to_lens = safe_normalize(-point)
    return to_lens, (to_lens if eye is None else safe_normalize(eye - point))


def _lobe_radiances(
    brdf: BRDF, light: AbstractLight, point: Vec3, normal: Vec3, pixel: Pixel, eye=None
):
    """`shade_columns` as a tuple of scalars (stacked, they are one XLA concatenation)."""
    to_lens, view = _directions(point, eye)
    sources = light.sources(point, to_lens, pixel)
    return tuple(
        sum(
            irradiance * lobe.radiance(normal, direction, view) for direction, irradiance in sources
        )
        for lobe in brdf.lobes
    )


def shade(
    brdf: BRDF,
    light: AbstractLight,
    point: Vec3,
    normal: Vec3,
    pixel: Pixel,
    effects: tuple[AbstractImageEffect, ...] = (),
    frame=0,
    eye: Vec3 | None = None,
) -> RGB:
    """One pixel's RGB value (linear units, 1.0 = 8-bit level 255): the physics of ctjax.

    `point` is the surface point and `normal` its unit normal, camera frame (mm); `pixel`
    the (u, v) it is seen at, in the capture's frame `frame` (for effects that depend on
    it: an exposure per frame). `eye`: where the camera that sees the point is, in the
    same frame, when it is not the lens the light is mounted on (the origin, default): a
    stereo laparoscope's right camera sees the surface from `-R^T T` while the light stays
    beside the left lens (`ctjax.io._stereo`).
    """
    to_lens, view = _directions(point, eye)
    radiance = sum(
        irradiance * brdf.radiance(normal, direction, view)
        for direction, irradiance in light.sources(point, to_lens, pixel)
    )
    return apply_effects(effects, radiance, Site(pixel, jnp.asarray(frame)))


def _pixel_grid(camera: Camera, dtype) -> tuple[Float[Array, "H W"], Float[Array, "H W"]]:
    """Pixel centres (u, v) as (H, W) arrays; XLA fuses these iotas, nothing is read."""
    shape = (camera.height, camera.width)
    u = jnp.broadcast_to(jnp.arange(camera.width, dtype=dtype), shape)
    v = jnp.broadcast_to(jnp.arange(camera.height, dtype=dtype)[:, None], shape)
    return u, v


def as_planar(field: Vec3 | Float[Array, "H W 3"], name: str, camera: Camera) -> Vec3:
    """A per-pixel vector field as a `Vec3` of (H, W) arrays (the renderer's fast layout)."""
    shape = (camera.height, camera.width)
    if not isinstance(field, Vec3):
        field = jnp.asarray(field)
        if field.shape != (*shape, 3):
            raise ParameterError(f"{name} must have shape {(*shape, 3)}, got {field.shape}")
        field = Vec3.from_array(field)
    for part in (field.x, field.y, field.z):
        if jnp.shape(part) != shape:
            raise ParameterError(
                f"{name} components must have shape {shape}, got {jnp.shape(part)}"
            )
    return field


def _surface(camera: Camera, pixel: Pixel, normal: Vec3, position, from_points: bool):
    """One pixel's surface point, unit normal and validity (1 valid, 0 not).

    A pixel is valid where its depth (or point) and normal are finite and its depth > 0.
    Invalid inputs are replaced by harmless ones *before* the physics, so neither values nor
    gradients see a NaN: a point 1 mm ahead, facing us. The point's stand-in depends on the
    point alone and the normal's on the normal: XLA computes the per-pixel view direction
    from the depth alone, not from all four inputs (10-20% faster, `benchmarks/render.py`).
    """
    if from_points:
        here = jnp.isfinite(position @ position) & (position.z > 0)
        point = where(here, position, Vec3(0.0, 0.0, 1.0))
    else:
        here = jnp.isfinite(position) & (position > 0)
        point = camera.backproject(pixel, jnp.where(here, position, 1))
    facing = jnp.isfinite(normal @ normal)
    normal = where(facing, normal, Vec3(0.0, 0.0, -1.0))
    return point, normal, (here & facing).astype(point.z.dtype)


def _map_surface(per_pixel, camera: Camera, normals, depth, points):
    """`per_pixel(point, normal, pixel, valid)` batched over the image: a pytree of
    (H, W, ...) arrays.

    Batched over rows and columns, not over flattened pixels: XLA's loop then has the
    pixel's row and column as indices instead of dividing a flat index by the width
    (the first program of `render` 9-16% faster on one core, in-cache 1024x768 float32).
    """
    u, v = _pixel_grid(camera, normals.x.dtype)

    def one(pixel, normal, position):
        point, normal, valid = _surface(camera, pixel, normal, position, points is not None)
        return per_pixel(point, normal, pixel, valid)

    position = depth if points is None else points
    return jax.vmap(jax.vmap(one))((u, v), normals, position)


def map_pixels(per_pixel, camera: Camera, normals, depth=None, points=None):
    """Batch `per_pixel(point, normal, pixel) -> (C,)` over the image; result (H, W, C).

    The inputs are `Vec3`s of (H, W) arrays (one array per component). A pixel is valid
    where its depth (or point) and normal are finite and its depth > 0; elsewhere the result
    is 0. Invalid inputs are replaced by harmless ones *before* the physics, so neither
    values nor gradients see a NaN.
    """

    def one(point, normal, pixel, valid):
        # Multiply, not `where`: the stand-ins keep the value finite, so x * 0 = 0 with a zero
        # gradient, and a select on the (pixels, C) output measured 2x slower on CPU.
        return per_pixel(point, normal, pixel) * valid

    return _map_surface(one, camera, normals, depth, points)


def _geometry(camera: Camera, normals, depth, points) -> tuple[Vec3, Array | None, Vec3 | None]:
    if (depth is None) == (points is None):
        raise ParameterError("give exactly one of depth (H, W) or points (H, W, 3)")
    normals = as_planar(normals, "normals", camera)
    dtype = jnp.result_type(normals.x)
    if not jnp.issubdtype(dtype, jnp.floating):
        raise ParameterError(f"normals must be floating point, got {dtype}")
    if points is not None:
        return normals, None, cast_floating(as_planar(points, "points", camera), dtype)
    depth = jnp.asarray(depth, dtype)
    if depth.shape != (camera.height, camera.width):
        raise ParameterError(
            f"depth must have shape {(camera.height, camera.width)}, got {depth.shape}"
        )
    return normals, depth, None


def _pack(values: tuple[Scalar, ...]) -> tuple[Array, ...]:
    """Per-pixel scalars two to a complex number (the last one alone if K is odd).

    XLA on CPU gives each output of a fused loop a loop of its own (no multi-output fusion):
    K scalars per pixel as K arrays would repeat the pixel's geometry K times. A complex
    array holds two in one output, computed in one pass over the geometry.
    """
    pairs = [jax.lax.complex(values[k], values[k + 1]) for k in range(0, len(values) - 1, 2)]
    return (*pairs, values[-1]) if len(values) % 2 else tuple(pairs)


def _unpack(packed: tuple[Array, ...]) -> list[Array]:
    """`_pack`'s scalars, in order."""
    values = []
    for part in packed:
        values += [part.real, part.imag] if jnp.iscomplexobj(part) else [part]
    return values


@eqx.filter_jit
def _packed_columns(brdf, light, camera, normals, depth, points, with_validity: bool):
    """The renderer's first program: each pixel's lobe columns (irradiance included, 0 where
    the geometry is invalid; and the validity itself if asked), packed by `_pack`."""
    normals, depth, points = _geometry(camera, normals, depth, points)
    brdf, light, camera = cast_floating((brdf, light, camera), normals.x.dtype)

    def per_pixel(point, normal, pixel, valid):
        columns = tuple(c * valid for c in _lobe_radiances(brdf, light, point, normal, pixel))
        return _pack((*columns, valid) if with_validity else columns)

    return _map_surface(per_pixel, camera, normals, depth, points)


@eqx.filter_jit
def _combined(brdf, effects, packed, frame):
    """The renderer's second program: RGB from the packed columns, effects applied (at
    each pixel of capture frame `frame`)."""
    columns = [c[..., None] for c in _unpack(packed)]
    brdf, effects = cast_floating((brdf, effects), columns[0].dtype)
    weights = brdf.weights
    # An explicit sum, not a matmul (see `BRDF.radiance`).
    rgb = sum(weights[k] * columns[k] for k in range(len(weights)))
    if effects:  # `_packed_columns` then appended each pixel's validity
        height, width = rgb.shape[:2]
        u = jnp.broadcast_to(jnp.arange(width, dtype=rgb.dtype), (height, width))
        v = jnp.broadcast_to(jnp.arange(height, dtype=rgb.dtype)[:, None], (height, width))

        def one(value, u, v):
            return apply_effects(effects, value, Site((u, v), frame))

        rgb = jax.vmap(jax.vmap(one))(rgb, u, v) * columns[-1]
    return rgb


def render(
    brdf: BRDF,
    light: AbstractLight,
    camera: Camera,
    normals: Vec3 | Float[Array, "H W 3"],
    depth: Float[Array, "H W"] | None = None,
    *,
    points: Vec3 | Float[Array, "H W 3"] | None = None,
    effects: tuple[AbstractImageEffect, ...] = (),
    frame: int = 0,
) -> Float[Array, "H W 3"]:
    """Render a linear RGB image of a surface seen by `camera` under `light`.

    **Arguments:**

    - `brdf`: the reflectance model (a sum of lobes).
    - `light`: the laparoscope's light, camera frame.
    - `camera`: intrinsics (the image is rendered without distortion).
    - `normals`: unit surface normals, camera frame: (H, W, 3), or a `Vec3` of three (H, W)
      arrays (the fast layout: no transposition inside).
    - `depth`: camera-frame z per pixel in mm (H, W); or `points`: camera-frame points in mm,
      (H, W, 3) or a `Vec3`. Exactly one of the two.
    - `effects`: per-pixel image effects (ambient, camera response), applied in order.
    - `frame`: the image's index in its capture, for effects that depend on it (an
      exposure per frame).

    **Returns:** linear RGB, (H, W, 3), 1.0 = 8-bit level 255, unclipped. Pixels without
    valid geometry (non-finite or non-positive depth, non-finite normal) are 0. Differentiable
    with respect to every parameter of the models, the normals, the depth and the light; the
    dtype follows the inputs (float32 or float64).

    The image is `shade` at every pixel, computed by two compiled programs: the lobes'
    columns per pixel (one pass over the geometry, two columns per complex number), then
    their weighted sum per channel. One program writing (H, W, 3) directly made XLA keep
    the expensive per-pixel terms in temporaries and read the geometry three times: 68
    bytes of memory traffic per float32 pixel against 44, and 1.3-1.4x the time at 1080p
    (`benchmarks/render.py`). Inside a caller's `jit` both are traced into its program.
    """
    packed = _packed_columns(brdf, light, camera, normals, depth, points, bool(effects))
    return _combined(brdf, effects, packed, jnp.asarray(frame, jnp.int32))


@eqx.filter_jit
def render_columns(
    brdf: BRDF,
    light: AbstractLight,
    camera: Camera,
    normals: Vec3 | Float[Array, "H W 3"],
    depth: Float[Array, "H W"] | None = None,
    *,
    points: Vec3 | Float[Array, "H W 3"] | None = None,
) -> Float[Array, "H W K"]:
    """Per-lobe radiance images for unit weights (irradiance included, no effects).

    The linear design matrix of the weights: without effects,
    `render(...) == render_columns(...) @ brdf.weights`.
    """
    normals, depth, points = _geometry(camera, normals, depth, points)
    brdf, light, camera = cast_floating((brdf, light, camera), normals.x.dtype)

    def per_pixel(point, normal, pixel):
        return shade_columns(brdf, light, point, normal, pixel)

    return map_pixels(per_pixel, camera, normals, depth, points)
