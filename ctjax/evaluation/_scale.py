"""Metric scale for shape known up to scale: the paper's known bounding-box volume."""

import numpy as np

from .._camera import Camera
from .._errors import CtjaxError
from .._geometry import points_from_depth


def bounding_box_volume(depth: np.ndarray, mask: np.ndarray, camera: Camera) -> float:
    """Volume (mm^3) of the axis-aligned bounding box, in the camera frame, of the surface
    points seen at the pixels of `mask` with z-depth `depth`."""
    points = points_from_depth(camera, depth)[mask]
    if len(points) < 2 or not np.all(np.isfinite(points)):
        raise CtjaxError("bounding-box volume: needs finite depth at two pixels or more")
    return float(np.prod(points.max(axis=0) - points.min(axis=0)))


def scale_to_volume(
    depth: np.ndarray, mask: np.ndarray, camera: Camera, volume_mm3: float
) -> np.ndarray:
    """`depth` (up to scale) scaled so that its bounding box has `volume_mm3`: every point
    scales with the depth, so the volume with its cube."""
    if not (np.isfinite(volume_mm3) and volume_mm3 > 0):
        raise CtjaxError(f"the known volume must be positive, got {volume_mm3} mm^3")
    current = bounding_box_volume(depth, mask, camera)
    if current <= 0:
        raise CtjaxError("bounding-box volume: the surface is flat along an axis")
    return depth * (volume_mm3 / current) ** (1 / 3)
