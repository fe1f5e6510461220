"""Depth on the pixel grid seen through a perspective camera: log-depth gradients <-> normals.

A surface imaged by the camera is z(u, v) = ln Z(u, v) (Z the depth along the optical axis,
mm). The camera-frame point is P = Z r with r = ((u - cx)/fx, (v - cy)/fy, 1), and with
p = dz/du, q = dz/dv (per pixel) the unit normal facing the camera is

    N ~ (fx p, fy q, -(1 + p (u - cx) + q (v - cy))),

independent of the depth's scale: shape from shading recovers z up to a constant, i.e. the
shape up to scale, which the known volume fixes afterwards. Gradients are backward
differences on the grid (p[i, j] = z[i, j] - z[i, j-1]), the same operator as Tsai-Shah's
discretisation and the integrator's, so normals -> gradients -> depth round-trips exactly.
"""

import jax.numpy as jnp
import numpy as np

from .._camera import Camera
from .._vector import Vec3

# Gradients are clipped where a normal is within ~0.5 degrees of grazing (N.r -> 0).
_GRAZING = 1e-2


def normal_from_gradients(p, q, pixel, camera: Camera) -> Vec3:
    """Unit normal (camera frame, facing the camera) of the surface with log-depth
    gradients `p = dz/du`, `q = dz/dv` at `pixel` (u, v). One pixel; vmap for batches."""
    u, v = pixel
    n = Vec3(camera.fx * p, camera.fy * q, -(1 + p * (u - camera.cx) + q * (v - camera.cy)))
    return n / jnp.sqrt(n @ n)


def gradients_from_normal(normal: Vec3, pixel, camera: Camera):
    """Inverse of `normal_from_gradients`: (p, q) of a camera-facing unit normal."""
    u, v = pixel
    ray = Vec3((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, jnp.ones_like(u))
    # N . r < 0 for a normal facing the camera; near 0 the surface is seen edge-on.
    facing = jnp.minimum(normal @ ray, -_GRAZING * jnp.sqrt(ray @ ray))
    t = -1 / facing
    return t * normal.x / camera.fx, t * normal.y / camera.fy


def backward_gradients(log_depth: np.ndarray, mask: np.ndarray):
    """Backward differences (p, q) of `log_depth` (H, W) and where they exist (both pixels
    in `mask`): p[i, j] = z[i, j] - z[i, j-1], q[i, j] = z[i, j] - z[i-1, j]."""
    z = np.where(mask, log_depth, 0.0)
    p = np.zeros_like(z)
    q = np.zeros_like(z)
    has_left = np.zeros_like(mask)
    has_up = np.zeros_like(mask)
    p[:, 1:] = z[:, 1:] - z[:, :-1]
    q[1:, :] = z[1:, :] - z[:-1, :]
    has_left[:, 1:] = mask[:, 1:] & mask[:, :-1]
    has_up[1:, :] = mask[1:, :] & mask[:-1, :]
    return np.where(has_left, p, 0.0), np.where(has_up, q, 0.0), has_left, has_up


def normals_from_log_depth(log_depth: np.ndarray, mask: np.ndarray, camera: Camera):
    """Unit normals (H, W, 3) of a log-depth map from its backward differences; NaN outside
    `mask`. Along a missing neighbour the gradient is taken as 0."""
    p, q, _, _ = backward_gradients(log_depth, mask)
    rows, cols = np.indices(log_depth.shape, dtype=np.float64)
    normal = normal_from_gradients(jnp.asarray(p), jnp.asarray(q), (cols, rows), camera)
    out = np.array(normal.to_array())
    out[~mask] = np.nan
    return out
