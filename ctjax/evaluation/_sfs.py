"""Shape from shading as evaluated in the paper: Tsai-Shah for the Lambertian model, and the
Cook-Torrance SfS that refines Tsai-Shah's normals per pixel (eq. 9) and integrates them."""

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._camera import Camera
from .._errors import CtjaxError
from .._vector import Vec3
from ._integrate import integrate_gradients
from ._perspective import backward_gradients, gradients_from_normal, normal_from_gradients
from ._refine import refine_normals
from ._scale import scale_to_volume
from ._tsai_shah import tsai_shah


@dataclasses.dataclass
class ShapeFromShading:
    """Depth (H, W, mm, NaN off the surface) at the known volume's scale, normals (H, W, 3),
    and, for the refined SfS, how many pixels' solves did not converge."""

    depth: np.ndarray
    normals: np.ndarray
    not_converged: int = 0
    refined_pixels: int = 0


def lambertian_shading(image: np.ndarray, rho_tilde) -> np.ndarray:
    """N.L of a Lambertian surface lit from the camera: the radiance summed over channels
    over the albedo summed over channels (rho_tilde / pi per channel)."""
    albedo = np.sum(np.asarray(rho_tilde, np.float64)) / np.pi
    if not albedo > 0:
        raise CtjaxError(f"Lambertian albedo must be positive, got rho_tilde {rho_tilde}")
    return np.sum(image, axis=-1) / albedo


def _normals(log_depth, mask, camera):
    p, q, _, _ = backward_gradients(log_depth, mask)
    rows, cols = np.indices(mask.shape, dtype=np.float64)
    return normal_from_gradients(jnp.asarray(p), jnp.asarray(q), (cols, rows), camera)


def _depth(log_depth, mask, camera, volume_mm3):
    relative = np.exp(log_depth - np.nanmean(log_depth[mask]))
    return scale_to_volume(np.where(mask, relative, np.nan), mask, camera, volume_mm3)


def sfs_tsai_shah(
    image: np.ndarray, mask: np.ndarray, camera: Camera, rho_tilde, volume_mm3: float, **kwargs
) -> tuple[ShapeFromShading, np.ndarray]:
    """Tsai-Shah SfS of a frame under the Lambertian model with albedo `rho_tilde`, at the
    scale of the known bounding-box volume. Returns the result and the log depth."""
    log_depth = tsai_shah(lambertian_shading(image, rho_tilde), mask, camera, **kwargs)
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
) -> ShapeFromShading:
    """The paper's Cook-Torrance SfS: from a starting surface (Tsai-Shah's), refine every
    pixel's normal under `model` (eq. 9, `refine_normals`), integrate the normals to log depth
    (least squares), and repeat `rounds` times from the integrated surface (each round makes
    the normals integrable again). The model's light may depend on the surface point (a near
    light): points come from the current surface at the known volume's scale."""
    rows, cols = np.nonzero(mask)
    pixels = (jnp.asarray(cols, np.float64), jnp.asarray(rows, np.float64))
    values = jnp.asarray(image[rows, cols], np.float64)
    log_depth = start_log_depth
    not_converged = 0
    for _ in range(rounds):
        depth = _depth(log_depth, mask, camera, volume_mm3)
        normals = _normals(log_depth, mask, camera)
        start = Vec3(*(jnp.asarray(c)[rows, cols] for c in (normals.x, normals.y, normals.z)))
        points = camera.backproject(pixels, jnp.asarray(depth[rows, cols]))
        refined = refine_normals(model, points, start, pixels, values, max_steps=max_steps)
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
