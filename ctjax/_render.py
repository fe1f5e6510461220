"""The renderer: physics for one pixel (`shade`), batched over an image by `vmap`, jitted.

Layout, measured on a 2-core CPU: geometry goes in as one array per component (`Vec3` of
(H, W) arrays, so XLA vectorises along pixels; (H, W, 3) inputs batch into (pixels, 3)
arrays and ran 6-7x slower in a prototype), and the image comes out interleaved (H, W, 3),
so the one fused loop computes a pixel's three channels together instead of re-reading the
geometry once per channel.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ._camera import Camera
from ._convert import cast_floating
from ._errors import ParameterError
from ._numerics import safe_normalize
from ._typing import RGB, Array, Float, Pixel
from ._vector import Vec3, where
from .effects import AbstractImageEffect
from .lights import AbstractLight
from .lobes import BRDF


def apply_effects(effects: tuple[AbstractImageEffect, ...], rgb: RGB) -> RGB:
    """Apply per-pixel image effects in order."""
    for effect in effects:
        rgb = effect(rgb)
    return rgb


def shade_columns(
    brdf: BRDF, light: AbstractLight, point: Vec3, normal: Vec3, pixel: Pixel
) -> Float[Array, " K"]:
    """One pixel's radiance per lobe for unit weights: the linear design-matrix row.

    `point` is the surface point and `normal` its unit normal, camera frame (mm).
    """
    view = safe_normalize(-point)
    direction, irradiance = light.illuminate(point, view, pixel)
    return irradiance * brdf.columns(normal, direction, view)


def shade(
    brdf: BRDF,
    light: AbstractLight,
    point: Vec3,
    normal: Vec3,
    pixel: Pixel,
    effects: tuple[AbstractImageEffect, ...] = (),
) -> RGB:
    """One pixel's RGB value (linear units, 1.0 = 8-bit level 255): the physics of ctjax.

    `point` is the surface point and `normal` its unit normal, camera frame (mm); `pixel`
    the (u, v) it is seen at.
    """
    view = safe_normalize(-point)
    direction, irradiance = light.illuminate(point, view, pixel)
    return apply_effects(effects, irradiance * brdf.radiance(normal, direction, view))


def _pixel_grid(camera: Camera, dtype) -> tuple[Float[Array, " P"], Float[Array, " P"]]:
    """Pixel centres (u, v), row-major; XLA fuses these iotas, nothing is read from memory."""
    shape = (camera.height, camera.width)
    u = jnp.broadcast_to(jnp.arange(camera.width, dtype=dtype), shape)
    v = jnp.broadcast_to(jnp.arange(camera.height, dtype=dtype)[:, None], shape)
    return u.reshape(-1), v.reshape(-1)


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


def map_pixels(per_pixel, camera: Camera, normals, depth=None, points=None):
    """Batch `per_pixel(point, normal, pixel) -> (C,)` over the image; result (H, W, C).

    The inputs are `Vec3`s of (H, W) arrays (one array per component) and the output is
    interleaved: XLA then computes all C channels of a pixel from data already in cache.
    A pixel is valid where its depth (or point) and normal are finite and its depth > 0;
    elsewhere the result is 0. Invalid inputs are replaced by harmless ones *before* the
    physics, so neither values nor gradients see a NaN.
    """
    size = camera.height * camera.width
    normal = jax.tree_util.tree_map(lambda a: a.reshape(size), normals)
    pixels = _pixel_grid(camera, normal.x.dtype)
    flat = lambda a: a.reshape(size)  # noqa: E731
    position = flat(depth) if points is None else jax.tree_util.tree_map(flat, points)

    def one(pixel, normal, position):
        # Harmless stand-ins where the geometry is invalid: a point 1 mm ahead, facing us.
        # The point's stand-in depends on the point alone and the normal's on the normal:
        # XLA computes the per-pixel view direction (a sqrt and a division, kept in a
        # temporary) from the depth alone, not from all four inputs (12 of the 80 bytes a
        # pixel cost at 1080p float32: 10-20% faster, `benchmarks/render.py`).
        if points is None:
            here = jnp.isfinite(position) & (position > 0)
            point = camera.backproject(pixel, jnp.where(here, position, 1))
        else:
            here = jnp.isfinite(position @ position) & (position.z > 0)
            point = where(here, position, Vec3(0.0, 0.0, 1.0))
        facing = jnp.isfinite(normal @ normal)
        normal = where(facing, normal, Vec3(0.0, 0.0, -1.0))
        ok = here & facing
        # Multiply, not `where`: the stand-ins keep the value finite, so x * 0 = 0 with a zero
        # gradient, and a select on the (pixels, C) output measured 2x slower on CPU.
        return per_pixel(point, normal, pixel) * ok.astype(point.z.dtype)

    out = jax.vmap(one)(pixels, normal, position)
    return out.reshape(camera.height, camera.width, -1)


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


@eqx.filter_jit
def render(
    brdf: BRDF,
    light: AbstractLight,
    camera: Camera,
    normals: Vec3 | Float[Array, "H W 3"],
    depth: Float[Array, "H W"] | None = None,
    *,
    points: Vec3 | Float[Array, "H W 3"] | None = None,
    effects: tuple[AbstractImageEffect, ...] = (),
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

    **Returns:** linear RGB, (H, W, 3), 1.0 = 8-bit level 255, unclipped. Pixels without
    valid geometry (non-finite or non-positive depth, non-finite normal) are 0. Differentiable
    with respect to every parameter of the models, the normals, the depth and the light; the
    dtype follows the inputs (float32 or float64).
    """
    normals, depth, points = _geometry(camera, normals, depth, points)
    brdf, light, camera, effects = cast_floating((brdf, light, camera, effects), normals.x.dtype)

    def per_pixel(point, normal, pixel):
        return shade(brdf, light, point, normal, pixel, effects)

    return map_pixels(per_pixel, camera, normals, depth, points)


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
