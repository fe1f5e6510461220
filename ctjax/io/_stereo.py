"""A stereo laparoscope's second camera: camera.json's `"stereo"` block and the right images.

    camera.json   "stereo": {"right": {"fx", "fy", "cx", "cy"} (+ optional k1 k2 p1 p2 k3,
                                     "width", "height": the left's by default),
                             "R": 3x3, "T": [3] (mm)}
    right/NAME.png   the right camera's image at the same instant as images/NAME.png

OpenCV's `stereoCalibrate` convention: a point's coordinates in the right camera's frame are
`X_right = R X_left + T`, in mm. The right images are encoded as the left ones are.
"""

import dataclasses
import math
from pathlib import Path

import numpy as np

from .._camera import Camera
from .._errors import CaptureError
from ._images import IMAGE_SUFFIXES

RIGHT = "right"


@dataclasses.dataclass(frozen=True)
class StereoRig:
    """The right camera (with its distortion) and its pose relative to the left:
    `X_right = R X_left + T` (mm)."""

    right: Camera
    R: np.ndarray  # (3, 3) rotation
    T: np.ndarray  # (3,) mm

    @property
    def baseline_mm(self) -> float:
        """The distance between the two cameras' centres (mm)."""
        return float(np.linalg.norm(self.T))

    def left_from_right(self) -> np.ndarray:
        """The right camera's pose in the left camera's frame (4x4, right-to-left):
        `X_left = R^T (X_right - T)`."""
        pose = np.eye(4)
        pose[:3, :3] = self.R.T
        pose[:3, 3] = -self.R.T @ self.T
        return pose

    def to_json(self) -> dict:
        return {"right": self.right.to_json(), "R": self.R.tolist(), "T": self.T.tolist()}


def _matrix(value, shape, where: str, key: str) -> np.ndarray:
    try:
        array = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise CaptureError(f"{where}: stereo.{key} must be numbers, got {value!r}") from None
    if array.shape != shape:
        raise CaptureError(f"{where}: stereo.{key} must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise CaptureError(f"{where}: stereo.{key} must be finite")
    return array


def parse_stereo(data, left: Camera, where: str, camera_from_json) -> StereoRig:
    """camera.json's `"stereo"` block (`data`), validated; `camera_from_json(dict, where)`
    parses the right camera as the left one is."""
    if not isinstance(data, dict):
        raise CaptureError(f"{where}: stereo must be an object with right, R and T")
    missing = [k for k in ("right", "R", "T") if k not in data]
    if missing:
        raise CaptureError(f"{where}: stereo is missing {', '.join(missing)}")
    right = data["right"]
    if not isinstance(right, dict):
        raise CaptureError(f"{where}: stereo.right must be an object with fx, fy, cx, cy")
    right = {"width": left.width, "height": left.height, **right}
    camera = camera_from_json(right, f"{where} (stereo.right)")
    R = _matrix(data["R"], (3, 3), where, "R")
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise CaptureError(f"{where}: stereo.R must be a rotation (orthonormal, det +1)")
    T = _matrix(np.ravel(data["T"]) if np.size(data["T"]) == 3 else data["T"], (3,), where, "T")
    if not math.isfinite(np.linalg.norm(T)) or np.linalg.norm(T) <= 0:
        raise CaptureError(f"{where}: stereo.T must be a nonzero translation (mm)")
    return StereoRig(camera, R, T)


def right_image_path(root: Path, name: str) -> Path | None:
    """The right camera's image of frame `name` (`right/NAME.*`), None where there is none."""
    for suffix in IMAGE_SUFFIXES:
        path = root / RIGHT / f"{name}{suffix}"
        if path.is_file():
            return path
    return None
