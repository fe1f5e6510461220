"""Shape from shading as evaluated in the paper: Tsai-Shah for the Lambertian model, and
shape from shading under the Cook-Torrance model.

Two Cook-Torrance SfS are here. `sfs_refined` is the paper's: Tsai-Shah's normals refined
per pixel by eq. (9), then integrated. Measured on synthetic organs it changes almost
nothing: where Lambertian Tsai-Shah reads a highlight's surroundings as facing the light
(the shading clips at 1, a plateau), N = L is a stationary point of every lobe, so the
per-pixel solve has no gradient to leave it, and one pixel's RGB leaves a cone of normals
about the light to choose from. `sfs_cook_torrance` puts the Cook-Torrance reflectance map
into Tsai-Shah's own formulation instead: every pixel's shading equation linearised in the
log depths of the pixel and its neighbours, all pixels solved jointly (one unknown per pixel:
the surface is integrable by construction, which removes the cone), coarse to fine from
Tsai-Shah's initial dome. On the same frames it recovers the depth to a fraction of a
millimetre where Tsai-Shah errs by millimetres around highlights.
"""

import dataclasses
import functools
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._camera import Camera
from .._errors import CtjaxError
from .._typing import Array, Float
from .._vector import Vec3
from ._integrate import integrate_gradients
from ._perspective import backward_gradients, gradients_from_normal, normal_from_gradients
from ._pyramid import block_reduce, reduced, resample
from ._refine import refine_normals
from ._scale import scale_to_volume
from ._tsai_shah import check_sfs_inputs, initial_log_depth, solve_log_depth, tsai_shah


@dataclasses.dataclass
class ShapeFromShading:
    """Depth (H, W, mm, NaN off the surface) at the known volume's scale, normals (H, W, 3),
    and, for the refined SfS, how many pixels' solves did not converge."""

    depth: np.ndarray
    normals: np.ndarray
    not_converged: int = 0
    refined_pixels: int = 0
    rms_levels: float | None = None  # final RMS of the shading residuals, 8-bit levels


def lambertian_shading(image: np.ndarray, rho_tilde, saturation=(1.0, 1.0, 1.0)) -> np.ndarray:
    """N.L of a Lambertian surface lit from the camera: the radiance summed over channels
    over the albedo summed over channels (rho_tilde / pi per channel). A channel at or above
    a ceiling below full scale (`saturation` under 1: `Capture.saturation`) is left out of
    both sums where another channel is not (at full scale a clipped channel counts, as
    Tsai-Shah clips the shading above 1)."""
    albedo = np.asarray(rho_tilde, np.float64) / np.pi
    if not np.sum(albedo) > 0:
        raise CtjaxError(f"Lambertian albedo must be positive, got rho_tilde {rho_tilde}")
    shading = np.sum(image, axis=-1) / np.sum(albedo)
    level = np.broadcast_to(np.asarray(saturation, np.float64), image.shape[-1:])
    if np.all(level >= 1.0):
        return shading
    light = (image < level) | (level >= 1.0)  # the channels read as light
    counted = np.sum(np.where(light, albedo, 0.0), axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        under = np.sum(np.where(light, image, 0.0), axis=-1) / counted
    return np.where(counted > 0, under, shading)


def _normals(log_depth, mask, camera):
    p, q, _, _ = backward_gradients(log_depth, mask)
    rows, cols = np.indices(mask.shape, dtype=np.float64)
    return normal_from_gradients(jnp.asarray(p), jnp.asarray(q), (cols, rows), camera)


def _depth(log_depth, mask, camera, volume_mm3):
    relative = np.exp(log_depth - np.nanmean(log_depth[mask]))
    return scale_to_volume(np.where(mask, relative, np.nan), mask, camera, volume_mm3)


def sfs_tsai_shah(
    image: np.ndarray,
    mask: np.ndarray,
    camera: Camera,
    rho_tilde,
    volume_mm3: float,
    saturation=(1.0, 1.0, 1.0),
    **kwargs,
) -> tuple[ShapeFromShading, np.ndarray]:
    """Tsai-Shah SfS of a frame under the Lambertian model with albedo `rho_tilde`, at the
    scale of the known bounding-box volume (`saturation`: `lambertian_shading`). Returns
    the result and the log depth."""
    shading = lambertian_shading(image, rho_tilde, saturation)
    log_depth = tsai_shah(shading, mask, camera, **kwargs)
    normals = np.array(_normals(log_depth, mask, camera).to_array())
    normals[~mask] = np.nan
    return ShapeFromShading(_depth(log_depth, mask, camera, volume_mm3), normals), log_depth


def sfs_refined(
    image: np.ndarray,
    mask: np.ndarray,
    camera: Camera,
    model,
    start_log_depth: np.ndarray,
    volume_mm3: float,
    *,
    rounds: int = 3,
    max_steps: int = 20,
    saturation=(1.0, 1.0, 1.0),
) -> ShapeFromShading:
    """The paper's Cook-Torrance SfS: from a starting surface (Tsai-Shah's), refine every
    pixel's normal under `model` (eq. 9, `refine_normals`), integrate the normals to log depth
    (least squares), and repeat `rounds` times from the integrated surface (each round makes
    the normals integrable again). The model's light may depend on the surface point (a near
    light): points come from the current surface at the known volume's scale. `saturation`:
    per channel, the level from which a value is clipped (`Capture.saturation`)."""
    rows, cols = np.nonzero(mask)
    pixels = (jnp.asarray(cols, np.float64), jnp.asarray(rows, np.float64))
    values = jnp.asarray(image[rows, cols], np.float64)
    saturation = jnp.broadcast_to(jnp.asarray(saturation, np.float64), values.shape[-1:])
    log_depth = start_log_depth
    not_converged = 0
    for _ in range(rounds):
        depth = _depth(log_depth, mask, camera, volume_mm3)
        normals = _normals(log_depth, mask, camera)
        start = Vec3(*(jnp.asarray(c)[rows, cols] for c in (normals.x, normals.y, normals.z)))
        points = camera.backproject(pixels, jnp.asarray(depth[rows, cols]))
        refined = refine_normals(
            model, points, start, pixels, values, saturation, max_steps=max_steps
        )
        not_converged = int(np.sum(np.asarray(refined.status) != 0))
        p, q = gradients_from_normal(Vec3.from_array(refined.normals), pixels, camera)
        p_map, q_map = np.zeros(mask.shape), np.zeros(mask.shape)
        p_map[rows, cols], q_map[rows, cols] = np.asarray(p), np.asarray(q)
        log_depth = integrate_gradients(p_map, q_map, mask)
    normals = np.array(_normals(log_depth, mask, camera).to_array())
    normals[~mask] = np.nan
    return ShapeFromShading(
        _depth(log_depth, mask, camera, volume_mm3), normals, not_converged, int(mask.sum())
    )


# Pyramid levels of the Cook-Torrance SfS (each halves the resolution): the joint cost has
# local minima at full resolution that the coarse levels step over (measured, 320x256
# organs at 160x128: from the dome at full resolution alone the final RMS stayed at 3-4
# levels and the depth 2-10 mm off; with 4 levels it reached the noise, depth 0.1-0.8 mm).
PYRAMID_LEVELS = 4
# Curvature weight of the Cook-Torrance SfS (residuals per channel over the frame's
# brightness / sqrt(C)). Measured on 160x128 frames with the true BRDF (mean depth error,
# mm): untextured organs 30: 0.09-0.75, 60: 0.14-0.33, 100: 1.4-1.8; the demo's 30%-contrast
# texture (read as shading by every uniform-albedo SfS) 30: 4.4-7.1, 60: 1.1-2.0, 100:
# 1.0-2.3, 300: 2.5-4.5. The weight is for a focal length of REFERENCE_FOCAL_PX and scales
# with its square: a second difference of log depth per pixel is the surface's curvature
# over f^2, so the same surface is held alike at any resolution.
COOK_TORRANCE_CURVATURE_WEIGHT = 60.0
REFERENCE_FOCAL_PX = 144.0
# Fewest pixels a pyramid level needs; coarser levels are skipped.
MIN_LEVEL_PIXELS = 64


def frame_brightness(image: np.ndarray, mask: np.ndarray, saturation=1.0) -> float:
    """A frame's brightness scale: the 99th percentile over the surface's unsaturated pixels
    (every channel under its `saturation`) of the channel sum. Residuals are divided by it so
    that the curvature weight, tuned in Tsai-Shah's N.L units, means the same whatever the
    exposure."""
    values = image[mask]
    values = values[np.all(values < saturation, axis=-1)]
    if len(values) == 0:
        raise CtjaxError("shape from shading: every pixel of the surface is saturated")
    brightness = float(np.percentile(values.sum(axis=-1), 99))
    if not brightness > 0:
        raise CtjaxError("shape from shading: the frame is black")
    return brightness


class ReflectanceResiduals(eqx.Module):
    """One pixel's shading residuals (C,) under `model` in Tsai-Shah's formulation: the
    normal from the log-depth gradients (p, q), the point at depth `depth_scale * exp(z)` (a
    near light sees the distance), the prediction and the value clipped at each channel's
    `saturation` (1, or the camera's ceiling: a clipped value only says "at least this
    bright"), in units of `unit` per channel."""

    model: eqx.Module
    camera: Camera
    depth_scale: Float[Array, ""]
    unit: Float[Array, ""]
    saturation: Float[Array, " C"]

    def __call__(self, z, p, q, u, v, values):
        normal = normal_from_gradients(p, q, (u, v), self.camera)
        point = self.camera.backproject((u, v), self.depth_scale * jnp.exp(z))
        predicted = jnp.minimum(self.model(point, normal, (u, v)), self.saturation)
        return (predicted - jnp.minimum(values, self.saturation)) / self.unit


def _solve_level(
    model, camera, mask, values, unit, saturation, curvature_weight, scale, start, iterations
):
    """One pyramid level of `sfs_cook_torrance`: (log depth, RMS)."""
    return solve_log_depth(
        ReflectanceResiduals(model, camera, jnp.asarray(scale), unit, saturation),
        mask,
        camera,
        start,
        values=values,
        iterations=iterations,
        curvature_weight=curvature_weight,
        differences="central",
    )


def _depth_scale(log_depth, mask, camera, volume_mm3, solve) -> float:
    """The metric depth a near light sees is `scale * exp(log_depth)`: the known volume's
    scale of the starting shape, unless the image says otherwise (a light with fall-off
    makes brightness depend on distance): the scale, within a factor 16 of the volume's,
    whose start explains the image best. Kept through the levels: the solve's log depth
    carries any further change of distance."""
    depth = _depth(log_depth, mask, camera, volume_mm3)
    volume_scale = float(np.median(depth[mask] / np.exp(log_depth[mask])))
    # Candidates ordered by distance from the volume's scale: a tie keeps the nearest.
    steps = sorted(range(-8, 9), key=abs)
    costs = [solve(volume_scale * 2 ** (k / 2), log_depth, 0)[1] for k in steps]
    best = int(np.argmin(np.round(np.asarray(costs), 9)))
    return volume_scale * 2 ** (steps[best] / 2)


def sfs_cook_torrance(
    image: np.ndarray,
    mask: np.ndarray,
    camera: Camera,
    model,
    volume_mm3: float,
    *,
    start: np.ndarray | None = None,
    levels: int = PYRAMID_LEVELS,
    iterations: int = 20,
    curvature_weight: float | None = None,
    saturation=(1.0, 1.0, 1.0),
) -> tuple[ShapeFromShading, np.ndarray]:
    """Shape from shading under `model` (a `ShadingModel`: Cook-Torrance, its light and
    effects): Tsai-Shah's linearisation with the model's reflectance map, all pixels jointly
    (central differences, so that each pixel's normal is the one at its centre), coarse to
    fine over `levels` pyramid levels from `start` (log depth (H, W); default Tsai-Shah's
    dome), at the scale of the known bounding-box volume `volume_mm3`. `curvature_weight`:
    default COOK_TORRANCE_CURVATURE_WEIGHT at the camera's focal length. `saturation`: per
    channel, the level from which a value is clipped (`Capture.saturation`). Returns the
    result and the log depth."""
    image = np.asarray(image, np.float64)
    mask = np.asarray(mask, bool)
    if image.ndim != 3:
        raise CtjaxError(
            f"shape from shading: image {image.shape} must be (height, width, channels) = "
            f"({camera.height}, {camera.width}, C)"
        )
    check_sfs_inputs(image, mask, camera, "Cook-Torrance shape from shading")
    if levels < 1:
        raise CtjaxError(f"Cook-Torrance shape from shading: levels must be >= 1, got {levels}")
    saturation = np.broadcast_to(np.asarray(saturation, np.float64), image.shape[-1:])
    unit = jnp.asarray(frame_brightness(image, mask, saturation) / math.sqrt(image.shape[-1]))
    if curvature_weight is None:
        focal = math.sqrt(float(camera.fx) * float(camera.fy))
        curvature_weight = COOK_TORRANCE_CURVATURE_WEIGHT * (focal / REFERENCE_FOCAL_PX) ** 2
    log_depth = initial_log_depth(camera) if start is None else np.asarray(start, np.float64)
    known = mask
    rms = math.nan
    factors = [2**k for k in reversed(range(levels))]
    factors = [
        f for f in factors if f == 1 or block_reduce(mask, f, np.all).sum() >= MIN_LEVEL_PIXELS
    ]
    scale = None
    for factor in factors:
        level_camera = reduced(camera, factor)
        level_mask = block_reduce(mask, factor, np.all)
        level_start = resample(log_depth, known, level_mask.shape)
        rows, cols = np.nonzero(level_mask)
        values = block_reduce(image, factor)[rows, cols]

        solve = functools.partial(
            _solve_level,
            model,
            level_camera,
            level_mask,
            values,
            unit,
            jnp.asarray(saturation),
            curvature_weight,
        )
        if scale is None:
            scale = _depth_scale(level_start, level_mask, level_camera, volume_mm3, solve)
        log_depth, rms = solve(scale, level_start, iterations)
        known = level_mask
    normals = np.array(_normals(log_depth, mask, camera).to_array())
    normals[~mask] = np.nan
    result = ShapeFromShading(
        _depth(log_depth, mask, camera, volume_mm3),
        normals,
        rms_levels=float(255.0 * rms * unit),
    )
    return result, log_depth
