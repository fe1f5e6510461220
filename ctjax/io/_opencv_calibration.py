"""A camera calibration as OpenCV writes it (`cv::FileStorage`, YAML or XML), read as
camera.json's content: SCARED's `endoscope_calibration.yaml` and what `stereoCalibrate`
scripts save, so that `ctjax import VIDEO --camera CALIBRATION.yaml` needs no conversion.

    M1 (or K1, KL, cameraMatrix1, camera_matrix, K)   3x3, the left camera's (or the only)
    D1 (or DL, distCoeffs1, distortion_coefficients)  its distortion, OpenCV's order
    M2, D2 (or K2 / KR, D2 / DR, cameraMatrix2, ...)  the right camera's: a stereo rig
    R (3x3), T (3)                                    X_right = R X_left + T

Each matrix may be an `!!opencv-matrix`, a plain list (of rows), or ROS's camera_info form
(rows, cols, data). A file has no image size that ctjax could trust (most omit it), so the
size is the frames' (`width`, `height`: one camera's image in the video). T is read in
millimetres, the unit of camera.json's `"stereo"` block (OpenCV's T is in the calibration
target's unit: SCARED's and most laparoscope calibrations are in mm). Distortion terms
beyond OpenCV's first eight (its rational model's; thin-prism and tilted-sensor terms)
are refused unless zero, as camera.json's are
(`ctjax.io._camera_json`).
"""

from pathlib import Path

import cv2
import numpy as np

from .._camera import DISTORTION_KEYS
from .._errors import CaptureError
from ._camera_json import camera_from_json
from ._stereo import parse_stereo

OPENCV_SUFFIXES = (".yaml", ".yml", ".xml")

# The names OpenCV's samples, SCARED and common calibration scripts give each matrix.
LEFT_MATRIX = ("M1", "K1", "KL", "cameraMatrix1", "camera_matrix", "cameraMatrix", "K")
LEFT_DISTORTION = (
    "D1", "DL", "distCoeffs1", "dist_coeffs", "distCoeffs", "distortion_coefficients", "D",
)  # fmt: skip
RIGHT_MATRIX = ("M2", "K2", "KR", "cameraMatrix2")
RIGHT_DISTORTION = ("D2", "DR", "distCoeffs2")

# OpenCV's distortion vector, in its order (4, 5, 8, 12 or 14 terms): the first eight are
# camera.json's keys; the rest keep OpenCV's names, which camera.json refuses unless zero.
_OPENCV_DISTORTION = (*DISTORTION_KEYS, "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tauX", "tauY")


def is_opencv_calibration(path: str | Path) -> bool:
    """Whether `path` names an OpenCV calibration file (by its suffix) and not camera.json."""
    return Path(path).suffix.lower() in OPENCV_SUFFIXES


def _numbers(node):
    """A FileStorage sequence's numbers, nested as its sequences are."""
    if node.isSeq():
        return [_numbers(node.at(i)) for i in range(node.size())]
    if node.isReal() or node.isInt():
        return node.real()
    raise ValueError("not a number")


def _read(storage, names: tuple[str, ...], path: Path):
    """The first of `names` in the file, as a float64 array, and its name; (None, None)."""
    for name in names:
        node = storage.getNode(name)
        if node.empty():
            continue
        try:
            if node.isSeq():  # a plain YAML list (of lists) rather than an !!opencv-matrix
                value = np.array(_numbers(node))
            elif node.isMap() and node.getNode("dt").empty():  # ROS's camera_info YAML
                rows, columns = int(node.getNode("rows").real()), int(node.getNode("cols").real())
                value = np.array(_numbers(node.getNode("data"))).reshape(rows, columns)
            else:
                value = node.mat()
        except (cv2.error, ValueError):
            value = None
        if value is None or value.dtype == object:
            raise CaptureError(f"{path}: {name} is not a matrix of numbers")
        if value.dtype == np.float32:  # "dt: f": the file's digits, not float32's binary
            value = np.array([float(str(v)) for v in value.ravel()]).reshape(value.shape)
        value = np.asarray(value, np.float64)
        if not np.all(np.isfinite(value)):
            raise CaptureError(f"{path}: {name} must be finite")
        return value, name
    return None, None


def _camera(matrix, matrix_name, distortion, distortion_name, size, path) -> dict:
    if matrix.shape != (3, 3):
        raise CaptureError(f"{path}: {matrix_name} must be a 3x3 camera matrix, got {matrix.shape}")
    if matrix[0, 1] != 0 or np.any(matrix[2] != (0, 0, 1)) or matrix[1, 0] != 0:
        raise CaptureError(
            f"{path}: {matrix_name} must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), "
            f"got {matrix.tolist()}"
        )
    described = {
        "width": size[0],
        "height": size[1],
        "fx": float(matrix[0, 0]),
        "fy": float(matrix[1, 1]),
        "cx": float(matrix[0, 2]),
        "cy": float(matrix[1, 2]),
    }
    if distortion is not None:
        terms = distortion.ravel()
        if terms.size not in (4, 5, 8, 12, 14):
            raise CaptureError(
                f"{path}: {distortion_name} has {terms.size} coefficients; OpenCV's distortion "
                "has 4, 5, 8, 12 or 14"
            )
        described.update(zip(_OPENCV_DISTORTION, map(float, terms), strict=False))
    return described


def camera_json_from_opencv(path: str | Path, width: int, height: int) -> dict:
    """camera.json's content (with its `"stereo"` block where the file has a right camera)
    from an OpenCV calibration file, for images `width` x `height` px; checked as camera.json
    is, each error naming the file and the matrix."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: calibration file not found")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        opened = storage.isOpened()
    except (cv2.error, SystemError) as error:  # OpenCV's parser raises either
        cause = error.__cause__ or error
        reason = (str(cause).strip().splitlines() or ["unreadable"])[-1][:200]
        raise CaptureError(f"{path}: not an OpenCV calibration file ({reason})") from None
    if not opened:
        raise CaptureError(f"{path}: cannot read it as an OpenCV calibration file (YAML or XML)")
    try:
        matrix, matrix_name = _read(storage, LEFT_MATRIX, path)
        distortion, distortion_name = _read(storage, LEFT_DISTORTION, path)
        right, right_name = _read(storage, RIGHT_MATRIX, path)
        right_distortion, right_distortion_name = _read(storage, RIGHT_DISTORTION, path)
        R, _ = _read(storage, ("R",), path)
        T, _ = _read(storage, ("T",), path)
    finally:
        storage.release()
    if matrix is None:
        raise CaptureError(f"{path}: no camera matrix (one of {', '.join(LEFT_MATRIX)})")
    size = (int(width), int(height))
    described = _camera(matrix, matrix_name, distortion, distortion_name, size, path)
    left = camera_from_json(described, path)
    if right is None:
        return described
    missing = [name for name, value in (("R", R), ("T", T)) if value is None]
    if missing:
        raise CaptureError(
            f"{path}: a right camera ({right_name}) without {' and '.join(missing)}: the pair's "
            "rotation R and translation T (X_right = R X_left + T) are needed"
        )
    stereo = {
        "right": _camera(right, right_name, right_distortion, right_distortion_name, size, path),
        "R": R.tolist(),
        "T": T.ravel().tolist(),
    }
    parse_stereo(stereo, left, str(path), camera_from_json)  # checked as camera.json's
    return {**described, "stereo": stereo}
