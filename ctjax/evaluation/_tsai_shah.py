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

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as sparse_linalg

from .._camera import Camera
from .._errors import CtjaxError
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


def lambertian_reflectance(p, q, pixel, camera: Camera):
    """N.L of the surface with log-depth gradients (p, q) at `pixel`, light at the camera."""
    u, v = pixel
    ray = Vec3((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, jnp.ones_like(u))
    light = -ray / jnp.sqrt(ray @ ray)
    return normal_from_gradients(p, q, pixel, camera) @ light


def initial_log_depth(camera: Camera) -> np.ndarray:
    """A shallow dome z0 = DOME * (x^2 + y^2) on normalised image coordinates."""
    rows, cols = np.indices((camera.height, camera.width), dtype=np.float64)
    x = (cols - float(camera.cx)) / float(camera.fx)
    y = (rows - float(camera.cy)) / float(camera.fy)
    return DOME * (x * x + y * y)


def _difference_operators(mask: np.ndarray):
    """Sparse backward differences (p, q) and second differences over the pixels of `mask`
    (rows where a neighbour is missing are empty)."""
    count = int(mask.sum())
    index = np.full(mask.shape, -1, np.int64)
    index[mask] = np.arange(count)
    here = index[mask]

    def first(neighbour):
        ok = neighbour[mask] >= 0
        rows = np.concatenate([np.nonzero(ok)[0]] * 2)
        cols = np.concatenate([here[ok], neighbour[mask][ok]])
        values = np.concatenate([np.ones(ok.sum()), -np.ones(ok.sum())])
        return sparse.csr_matrix((values, (rows, cols)), shape=(count, count))

    def shifted(dr, dc):
        out = np.full(mask.shape, -1, np.int64)
        h, w = mask.shape
        out[max(dr, 0) : h + min(dr, 0), max(dc, 0) : w + min(dc, 0)] = index[
            max(-dr, 0) : h + min(-dr, 0), max(-dc, 0) : w + min(-dc, 0)
        ]
        return out

    left, up = shifted(0, 1), shifted(1, 0)
    right, down = shifted(0, -1), shifted(-1, 0)
    second = []
    for before, after in ((left, right), (up, down)):
        ok = (before[mask] >= 0) & (after[mask] >= 0)
        n = int(ok.sum())
        rows = np.concatenate([np.arange(n)] * 3)
        cols = np.concatenate([here[ok], before[mask][ok], after[mask][ok]])
        values = np.concatenate([-2 * np.ones(n), np.ones(n), np.ones(n)])
        second.append(sparse.csr_matrix((values, (rows, cols)), shape=(n, count)))
    return first(left), first(up), sparse.vstack(second).tocsr()


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
    if shading.shape != (camera.height, camera.width) or mask.shape != shading.shape:
        raise CtjaxError(
            f"Tsai-Shah: shading {shading.shape} and mask {mask.shape} must both be "
            f"(height, width) = ({camera.height}, {camera.width})"
        )
    if mask.sum() < 9:
        raise CtjaxError(f"Tsai-Shah: the mask has {int(mask.sum())} pixel(s), needs 9 or more")
    if not np.all(np.isfinite(shading[mask])):
        raise CtjaxError("Tsai-Shah: the shading image has non-finite values inside the mask")
    measured = np.clip(shading[mask], 0.0, 1.0)
    rows, cols = np.nonzero(mask)
    pixel = (jnp.asarray(cols, np.float64), jnp.asarray(rows, np.float64))
    d_u, d_v, curvature = _difference_operators(mask)
    reflectance = jax.jit(
        jax.vmap(
            jax.value_and_grad(
                lambda p, q, u, v: lambertian_reflectance(p, q, (u, v), camera), (0, 1)
            )
        )
    )

    def linearise(z):
        value, (dp, dq) = reflectance(jnp.asarray(d_u @ z), jnp.asarray(d_v @ z), *pixel)
        residual = np.concatenate(
            [np.asarray(value) - measured, curvature_weight * (curvature @ z)]
        )
        return residual, (np.asarray(dp), np.asarray(dq))

    z = initial_log_depth(camera)[mask]
    residual, slopes = linearise(z)
    cost = residual @ residual
    damping = 1.0
    for _ in range(iterations):
        jacobian = sparse.vstack(
            [
                sparse.diags(slopes[0]) @ d_u + sparse.diags(slopes[1]) @ d_v,
                curvature_weight * curvature,
            ]
        ).tocsr()
        normal = (jacobian.T @ jacobian).tocsc()
        gradient = jacobian.T @ residual
        scaling = sparse.diags(normal.diagonal() + 1e-12)
        while damping < 1e8:
            step = sparse_linalg.spsolve(normal + damping * scaling, -gradient)
            trial, trial_slopes = linearise(z + step)
            trial_cost = trial @ trial
            if trial_cost < cost:
                z, residual, slopes, cost = z + step, trial, trial_slopes, trial_cost
                damping = max(damping / 3, 1e-6)
                break
            damping *= 4
        else:
            break
    out = np.full(mask.shape, np.nan)
    out[mask] = z
    return out
