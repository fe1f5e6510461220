"""Per-pixel geometry on the image grid: points from depth, normals from depth (NumPy, I/O side)."""

import numpy as np

from ._camera import Camera


def points_from_depth(camera: Camera, depth: np.ndarray) -> np.ndarray:
    """Camera-frame points (H, W, 3), mm, from z-depth (H, W); NaN where depth is NaN."""
    height, width = depth.shape
    u = np.arange(width, dtype=np.float64)[None, :]
    v = np.arange(height, dtype=np.float64)[:, None]
    z = depth.astype(np.float64)
    x = z * (u - float(camera.cx)) / float(camera.fx)
    y = z * (v - float(camera.cy)) / float(camera.fy)
    return np.stack([x, y, z], axis=-1)


def normals_from_depth(camera: Camera, depth: np.ndarray) -> np.ndarray:
    """Unit normals (H, W, 3) facing the camera, from z-depth by central differences.

    One-sided differences at the image border and next to missing depth; NaN where a pixel
    has no valid neighbour along a direction. float32, camera frame.
    """
    points = points_from_depth(camera, depth)
    du = _derivative(points, axis=1)
    dv = _derivative(points, axis=0)
    # x right, y down, z forward: dP/dv x dP/du points towards the camera (-z).
    normal = np.cross(dv, du)
    norm = np.linalg.norm(normal, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = np.where(norm > 0, normal / norm, np.nan)
    facing_away = np.sum(normal * points, axis=-1) > 0
    normal[facing_away] *= -1
    return normal.astype(np.float32)


def _derivative(points: np.ndarray, axis: int) -> np.ndarray:
    """Central difference along `axis`, falling back to one-sided where a neighbour is NaN."""
    forward = np.full_like(points, np.nan)
    backward = np.full_like(points, np.nan)
    n = points.shape[axis]
    hi = [slice(None)] * 3
    lo = [slice(None)] * 3
    hi[axis], lo[axis] = slice(1, n), slice(0, n - 1)
    difference = points[tuple(hi)] - points[tuple(lo)]
    forward[tuple(lo)] = difference
    backward[tuple(hi)] = difference
    central = 0.5 * (forward + backward)
    return np.where(
        np.isfinite(central), central, np.where(np.isfinite(forward), forward, backward)
    )
