"""camera.json: the camera's intrinsics and distortion (`read_camera`, `camera_from_json`),
a stereo laparoscope's right camera (`read_stereo`, its `"stereo"` block:
`ctjax.io._stereo`), the images' encoding (`read_encoding`) and the channels' ceilings
(`read_ceilings`), each checked with an error that names the file and the key."""

import json
import math
from pathlib import Path

import numpy as np

from .._camera import DISTORTION_KEYS, RATIONAL_KEYS, Camera
from .._errors import CaptureError
from ._encoding import declared_encoding
from ._stereo import StereoRig, parse_stereo


def _camera_json(path: Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: camera.json not found")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise CaptureError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(data, dict):
        raise CaptureError(f"{path}: expected a JSON object with width, height, fx, fy, cx, cy")
    return data


# A focal length (px) lies between the image's size over this and its size times it.
FOCAL_RANGE = 100.0


def read_camera(path: Path) -> Camera:
    """Parse and validate `camera.json`."""
    return camera_from_json(_camera_json(path), path)


def read_stereo(path: Path) -> StereoRig | None:
    """`camera.json`'s `"stereo"` block (the right camera of a stereo laparoscope,
    `ctjax.io._stereo`), None where there is none."""
    data = _camera_json(path)
    if "stereo" not in data:
        return None
    return parse_stereo(data["stereo"], camera_from_json(data, path), str(path), camera_from_json)


def camera_from_json(data: dict, path) -> Camera:
    """A `Camera` from camera.json's keys (`path` names it in errors)."""
    missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy") if k not in data]
    if missing:
        raise CaptureError(f"{path}: missing key(s) {', '.join(missing)}")
    values = {}
    for key in ("width", "height", "fx", "fy", "cx", "cy", *DISTORTION_KEYS, *RATIONAL_KEYS):
        if key not in data:
            continue
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CaptureError(f"{path}: {key} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise CaptureError(f"{path}: {key} must be finite, got {value!r}")
        values[key] = float(value)
    for key in ("width", "height"):
        if values[key] != int(values[key]) or values[key] <= 0:
            raise CaptureError(f"{path}: {key} must be a positive integer, got {data[key]!r}")
    for key, size in (("fx", "width"), ("fy", "height")):
        if values[key] <= 0:
            raise CaptureError(f"{path}: {key} must be positive, got {data[key]!r}")
        # A field of view over 177.7 degrees (a pinhole's) or under 0.57: not a camera's,
        # a wrong unit (metres for pixels); 1e-300 was read on and blamed the normals.
        if not values[size] / FOCAL_RANGE <= values[key] <= values[size] * FOCAL_RANGE:
            raise CaptureError(
                f"{path}: {key} {values[key]:g} px is not a focal length for an image "
                f"{values[size]:g} px {'wide' if key == 'fx' else 'high'} (from "
                f"{values[size] / FOCAL_RANGE:g} to {values[size] * FOCAL_RANGE:g} px)"
            )
    for key, size in (("cx", "width"), ("cy", "height")):
        # The principal point on the image, its edges included (pixel centres run from 0 to
        # size - 1); off it, the rays and every fit after them would be wrong.
        if not 0 <= values[key] <= values[size]:
            raise CaptureError(
                f"{path}: {key} {values[key]:g} is outside the image (0..{values[size]:g})"
            )
    _refuse_unsupported_distortion(data, path)
    distortion = None
    # OpenCV's five terms, or its rational model's eight where k4-k6 are not all zero.
    keys = (*DISTORTION_KEYS, *RATIONAL_KEYS)
    if not any(values.get(k, 0.0) for k in RATIONAL_KEYS):
        keys = DISTORTION_KEYS
    distortion = np.array([values.get(k, 0.0) for k in keys])
    if not np.any(distortion):
        distortion = None
    return Camera(
        int(values["width"]),
        int(values["height"]),
        values["fx"],
        values["fy"],
        values["cx"],
        values["cy"],
        distortion=None if distortion is None else np.asarray(distortion, np.float64),
    )


# Distortion coefficients of other models than the eight ctjax applies (OpenCV's thin-prism
# and tilted-sensor terms, an array of any length): refused unless zero, not silently dropped.
_UNSUPPORTED_DISTORTION = (
    "s1", "s2", "s3", "s4", "tauX", "tauY", "distortion", "dist_coeffs", "distortion_coefficients",
)  # fmt: skip


def _refuse_unsupported_distortion(data: dict, path) -> None:
    def zero(value) -> bool:
        try:
            return not np.any(np.asarray(value, np.float64))
        except (TypeError, ValueError):
            return False

    unsupported = [k for k in _UNSUPPORTED_DISTORTION if k in data and not zero(data[k])]
    if unsupported:
        raise CaptureError(
            f"{path}: unsupported distortion key(s) {', '.join(unsupported)}: ctjax applies "
            f"{', '.join((*DISTORTION_KEYS, *RATIONAL_KEYS))} (OpenCV's first eight "
            "coefficients, each its own key) "
            "and no other; undistort the images first, or refit the camera with those alone"
        )


def read_encoding(path: Path) -> str | None:
    """`camera.json`'s `"encoding"` ("srgb" or "linear"), or None where it does not say."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        return None  # `read_camera` names the problem
    return declared_encoding(data, str(path)) if isinstance(data, dict) else None


# camera.json's "ceilings": found on the frames (the default), none, or given.
AUTO_CEILINGS = "auto"
NO_CEILINGS = "none"


def read_ceilings(path: Path) -> str | list[int | None]:
    """`camera.json`'s `"ceilings"`: "auto" (the default: each channel's ceiling found on the
    frames, `ctjax.io._channel_ceiling`), "none" (every channel clips at full scale) or
    [R, G, B], each a code value of the images (from which that channel reads as clipped)
    or null (full scale). The same of reconstruction.json, where `ctjax reconstruct` keeps
    the ceilings it found on every frame."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        return AUTO_CEILINGS  # `read_camera` names the problem
    value = data.get("ceilings", AUTO_CEILINGS) if isinstance(data, dict) else AUTO_CEILINGS
    if value in (AUTO_CEILINGS, NO_CEILINGS):
        return value
    if (
        isinstance(value, list)
        and len(value) == 3
        and all(
            code is None or (isinstance(code, int) and not isinstance(code, bool) and code > 0)
            for code in value
        )
    ):
        return value
    raise CaptureError(
        f'{path}: "ceilings" must be "auto", "none" or [R, G, B] (each a positive code value '
        f"of the images, or null for full scale), got {value!r}"
    )
