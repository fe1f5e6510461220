"""Tsai and Shah's linear shape from shading (1994), for a perspective camera with the light
at its centre (the laparoscope's tip), on log depth.

Tsai-Shah discretise the surface gradient by backward differences, p[i, j] = z[i, j] -
z[i, j-1] and q[i, j] = z[i, j] - z[i-1, j], and linearise each pixel's irradiance equation
`E - R(p, q) = 0` in the depths. The published method then solves each pixel's linear
equation for its own depth, neighbours held (Jacobi), iterating. With the light at the camera
that march is unstable: the error at a pixel becomes a combination of its left and upper
neighbours' errors with weights dR/dp / (dR/dp + dR/dq) and dR/dq / (dR/dp + dR/dq), which
exceed 1 wherever dR/dp and dR/dq have opposite signs, i.e. in two quadrants about every
highlight (measured here: started at the true surface, it drifts away by 0.1 in log depth in
100 iterations). ctjax keeps Tsai-Shah's discretisation and linearisation but solves the
linearised equations of all pixels jointly, in least squares, with a small curvature penalty
(a Gauss-Newton / Levenberg-Marquardt step on the whole depth map; sparse). That has no
marching direction, so it is stable whatever the light.

The reflectance map is Lambertian with the light at the camera: with the perspective
gradients of `_perspective`, the radiance of a pixel is

    I = (rho / pi) N.L,   L = -r / |r|,   N.L = 1 / (|n(p, q)| |r|),

which does not depend on the depth's scale: the result is the shape up to scale. Brightness
above the model's maximum (highlights) is clipped to it.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as sparse_linalg

from .._buckets import bucket
from .._camera import Camera
from .._errors import CtjaxError
from .._programs import fitter_jit
from .._vector import Vec3
from ._perspective import normal_from_gradients

# With the light at the camera a flat surface is a stationary point of every pixel's equation
# (dR/dp = dR/dq = 0 on the optical axis): start from a shallow dome instead, which also picks
# the convex solution (an organ bulging towards the camera) over the concave one.
DOME = 0.1
# Weight of the curvature penalty (second differences of log depth) against the shading
# residuals (N.L units): chosen on synthetic organs (3 gave 20 mm error, 30 gave 2.7 mm
# median, 300 gave 4.0 mm on a 320x256 frame).
CURVATURE_WEIGHT = 30.0
# The normal equations are symmetric positive definite: SuperLU's minimum-degree ordering on
# A + A^T fills in less than its default COLAMD (measured 1.8x faster on 160x128 frames).
_ORDERING = "MMD_AT_PLUS_A"


def lambertian_reflectance(p, q, pixel, camera: Camera):
    """N.L of the surface with log-depth gradients (p, q) at `pixel`, light at the camera."""
    u, v = pixel
    ray = Vec3((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, jnp.ones_like(u))
    light = -ray / jnp.sqrt(ray @ ray)
    return normal_from_gradients(p, q, pixel, camera) @ light


class LambertianResiduals(eqx.Module):
    """Tsai-Shah's shading equation of one pixel, N.L - E (E the normalised shading)."""

    camera: Camera

    def __call__(self, z, p, q, u, v, shading):
        return lambertian_reflectance(p, q, (u, v), self.camera)[None] - shading


@fitter_jit
def _linearise(residuals, z, p, q, u, v, values):
    """Every pixel's residuals and their derivatives in (z, p, q), vmapped."""

    def one(*args):
        return residuals(*args), jax.jacfwd(residuals, (0, 1, 2))(*args)

    return jax.vmap(one)(z, p, q, u, v, values)


def initial_log_depth(camera: Camera) -> np.ndarray:
    """A shallow dome z0 = DOME * (x^2 + y^2) on normalised image coordinates."""
    rows, cols = np.indices((camera.height, camera.width), dtype=np.float64)
    x = (cols - float(camera.cx)) / float(camera.fx)
    y = (rows - float(camera.cy)) / float(camera.fy)
    return DOME * (x * x + y * y)


def _difference_operators(mask: np.ndarray, scheme: str = "backward"):
    """Sparse first differences (p, q) and second differences over the pixels of `mask`.

    `scheme` "backward" is Tsai-Shah's p[i, j] = z[i, j] - z[i, j-1] (rows where the
    neighbour is missing are empty); "central" is (z[i, j+1] - z[i, j-1]) / 2, centred on
    the pixel whose value it explains, one-sided where a neighbour is missing."""
    count = int(mask.sum())
    index = np.full(mask.shape, -1, np.int64)
    index[mask] = np.arange(count)
    here = index[mask]

    def shifted(dr, dc):
        out = np.full(mask.shape, -1, np.int64)
        h, w = mask.shape
        out[max(dr, 0) : h + min(dr, 0), max(dc, 0) : w + min(dc, 0)] = index[
            max(-dr, 0) : h + min(-dr, 0), max(-dc, 0) : w + min(-dc, 0)
        ]
        return out[mask]

    def matrix(rows, cols, values):
        return sparse.csr_matrix(
            (np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
            shape=(count, count),
        )

    def first(before, after):
        has_before, has_after = before >= 0, after >= 0
        if scheme == "backward":
            ok = np.nonzero(has_before)[0]
            return matrix([ok, ok], [here[ok], before[ok]], [np.ones(ok.size), -np.ones(ok.size)])
        both = np.nonzero(has_before & has_after)[0]
        back = np.nonzero(has_before & ~has_after)[0]
        ahead = np.nonzero(~has_before & has_after)[0]
        return matrix(
            [both, both, back, back, ahead, ahead],
            [after[both], before[both], here[back], before[back], after[ahead], here[ahead]],
            [
                np.full(both.size, 0.5),
                np.full(both.size, -0.5),
                np.ones(back.size),
                -np.ones(back.size),
                np.ones(ahead.size),
                -np.ones(ahead.size),
            ],
        )

    left, up = shifted(0, 1), shifted(1, 0)
    right, down = shifted(0, -1), shifted(-1, 0)
    second = []
    for before, after in ((left, right), (up, down)):
        ok = (before >= 0) & (after >= 0)
        n = int(ok.sum())
        rows = np.concatenate([np.arange(n)] * 3)
        cols = np.concatenate([here[ok], before[ok], after[ok]])
        values = np.concatenate([-2 * np.ones(n), np.ones(n), np.ones(n)])
        second.append(sparse.csr_matrix((values, (rows, cols)), shape=(n, count)))
    return first(left, right), first(up, down), sparse.vstack(second).tocsr()


def solve_log_depth(
    residuals: Callable,
    mask: np.ndarray,
    camera: Camera,
    start: np.ndarray,
    *,
    values: np.ndarray | None = None,
    iterations: int = 15,
    curvature_weight: float = CURVATURE_WEIGHT,
    differences: str = "backward",
    rtol: float = 1e-6,
) -> tuple[np.ndarray, float]:
    """The log depth (H, W) minimising every pixel's shading residuals plus the curvature
    penalty, by damped Gauss-Newton on all pixels jointly (sparse normal equations).

    `residuals(z, p, q, u, v, values)` is one pixel's residual vector (K,) as a JAX function
    of its log depth `z`, Tsai-Shah's backward-difference gradients `p`, `q`, its position
    (u, v) and its row of `values` (a (N, C) array, or None; N the pixels of `mask` in
    row-major order); it is linearised by autodiff, vmapped over the pixels: pass an
    `equinox.Module` (e.g. `LambertianResiduals`) so that the compiled linearisation is
    reused. `start` (H, W) is the initial log depth. `differences`: "backward" (Tsai-Shah's)
    or "central". Stops after `iterations` steps or when a step lowers the cost by less than
    `rtol` of it. Returns the log depth (NaN outside `mask`) and the final RMS of the shading
    residuals.
    """
    if differences not in ("backward", "central"):
        raise CtjaxError(f"differences must be 'backward' or 'central', got {differences!r}")
    rows, cols = np.nonzero(mask)
    pixel = (jnp.asarray(cols, np.float64), jnp.asarray(rows, np.float64))
    d_u, d_v, curvature = _difference_operators(mask, differences)
    count = len(rows)
    # Padded to a bucket size (`ctjax._buckets`), as the fitters' samples, so that frames of
    # one size reuse the compiled linearisation; until 2026-12-06 to the next power of two
    # (the demo's evaluate: shape from shading 22.1 -> 18.2 s, the same figures).
    padding = bucket(count) - count

    def padded(x):
        return jnp.asarray(
            np.pad(np.asarray(x), [(0, padding)] + [(0, 0)] * (np.ndim(x) - 1), "edge")
        )

    pixel = tuple(padded(c) for c in pixel)
    data = None if values is None else padded(values)

    def linearise(z):
        value, slopes = _linearise(
            residuals, padded(z), padded(d_u @ z), padded(d_v @ z), *pixel, data
        )
        value = np.asarray(value)[:count]
        residual = np.concatenate([value.T.reshape(-1), curvature_weight * (curvature @ z)])
        return residual, [np.asarray(s)[:count] for s in slopes], value.size

    z = np.asarray(start, np.float64)[mask]
    residual, slopes, size = linearise(z)
    cost = residual @ residual
    damping = 1.0
    for _ in range(iterations):
        # One block of rows per residual component k: dr_k/dz + dr_k/dp D_u + dr_k/dq D_v.
        blocks = [
            sparse.diags(slopes[0][:, k])
            + sparse.diags(slopes[1][:, k]) @ d_u
            + sparse.diags(slopes[2][:, k]) @ d_v
            for k in range(slopes[0].shape[1])
        ]
        jacobian = sparse.vstack([*blocks, curvature_weight * curvature]).tocsr()
        normal = (jacobian.T @ jacobian).tocsc()
        gradient = jacobian.T @ residual
        scaling = sparse.diags(normal.diagonal() + 1e-12)
        while damping < 1e8:
            step = sparse_linalg.spsolve(
                normal + damping * scaling, -gradient, permc_spec=_ORDERING
            )
            trial, trial_slopes, _ = linearise(z + step)
            trial_cost = trial @ trial
            if np.isfinite(trial_cost) and trial_cost < cost:
                converged = cost - trial_cost <= rtol * cost
                z, residual, slopes, cost = z + step, trial, trial_slopes, trial_cost
                damping = max(damping / 3, 1e-6)
                break
            damping *= 4
        else:
            break
        if converged:
            break
    out = np.full(mask.shape, np.nan)
    out[mask] = z
    return out, float(np.sqrt(np.mean(residual[:size] ** 2)))


def check_sfs_inputs(shading: np.ndarray, mask: np.ndarray, camera: Camera, what: str) -> None:
    if shading.shape[:2] != (camera.height, camera.width) or mask.shape != shading.shape[:2]:
        raise CtjaxError(
            f"{what}: image {shading.shape} and mask {mask.shape} must both be "
            f"(height, width) = ({camera.height}, {camera.width})"
        )
    if mask.sum() < 9:
        raise CtjaxError(f"{what}: the mask has {int(mask.sum())} pixel(s), needs 9 or more")
    if not np.all(np.isfinite(shading[mask])):
        raise CtjaxError(f"{what}: the image has non-finite values inside the mask")


def tsai_shah(
    shading: np.ndarray,
    mask: np.ndarray,
    camera: Camera,
    *,
    iterations: int = 15,
    curvature_weight: float = CURVATURE_WEIGHT,
) -> np.ndarray:
    """Log depth (H, W) from a normalised shading image: Tsai-Shah's linearisation, solved
    for all pixels jointly (see the module's docstring).

    `shading` is the radiance divided by the albedo (rho_tilde / pi), i.e. N.L, in [0, 1];
    values above 1 (highlights) are clipped. `mask` selects the pixels on the surface.
    Returns z = ln Z up to an additive constant (NaN outside `mask`).
    """
    shading = np.asarray(shading, np.float64)
    mask = np.asarray(mask, bool)
    check_sfs_inputs(shading, mask, camera, "Tsai-Shah")
    measured = np.clip(shading[mask], 0.0, 1.0)[:, None]
    log_depth, _ = solve_log_depth(
        LambertianResiduals(camera),
        mask,
        camera,
        initial_log_depth(camera),
        values=measured,
        iterations=iterations,
        curvature_weight=curvature_weight,
    )
    return log_depth
