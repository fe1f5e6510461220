"""A da Vinci's stereo calibration as its software writes it, `StereoCalibration.ini`
(StereoMIS and SurgPose ship it beside each video), read as camera.json's content, so that
`ctjax import VIDEO --top-bottom --camera StereoCalibration.ini` needs no conversion.

    [StereoLeft]    res_x, res_y                the calibrated image size (one camera's)
                    fc_x, fc_y, cc_x, cc_y      focal lengths and principal point (px)
                    kc_0 ... kc_7               distortion, OpenCV's order (k1 k2 p1 p2 k3
                                                k4 k5 k6; fewer may be given)
                    R_0 ... R_8, T_0 ... T_2    the camera in the rig's frame (the left:
                                                the identity and zero)
    [StereoRight]   the same keys; its R (row-major) and T (mm): X_right = R X_left + T

Where the left camera's R and T are not the identity and zero, the pair's R and T are
composed from both (X_cam = R_cam X_rig + T_cam). Frames of another size than res_x x res_y
with the same aspect (a video written smaller) take the intrinsics scaled, pixel centres
kept; any other size is refused.
"""

import configparser
from pathlib import Path

import numpy as np

from .._errors import CaptureError
from ._camera_json import camera_from_json
from ._stereo import parse_stereo

DAVINCI_SUFFIXES = (".ini",)
_SECTIONS = ("StereoLeft", "StereoRight")
_DISTORTION = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def is_davinci_calibration(path: str | Path) -> bool:
    """Whether `path` names a da Vinci calibration file (`StereoCalibration.ini`)."""
    return Path(path).suffix.lower() in DAVINCI_SUFFIXES


def _number(section, key: str, path: Path, default=None) -> float:
    if key not in section:
        if default is not None:
            return default
        raise CaptureError(f"{path}: [{section.name}] has no {key}")
    try:
        value = float(section[key])
    except ValueError:
        raise CaptureError(f"{path}: [{section.name}] {key} is not a number") from None
    if not np.isfinite(value):
        raise CaptureError(f"{path}: [{section.name}] {key} must be finite")
    return value


def _camera(section, path: Path, size: tuple[int, int], scale: float) -> dict:
    described = {"width": size[0], "height": size[1]}
    for key, name in (("fx", "fc_x"), ("fy", "fc_y")):
        described[key] = _number(section, name, path) * scale
    for key, name in (("cx", "cc_x"), ("cy", "cc_y")):  # pixel centres kept
        described[key] = (_number(section, name, path) + 0.5) * scale - 0.5
    for k, key in enumerate(_DISTORTION):
        if f"kc_{k}" in section:
            described[key] = _number(section, f"kc_{k}", path)
    return described


def _pose(section, path: Path, required: bool) -> tuple[np.ndarray, np.ndarray]:
    """A camera's R and T in the rig's frame (the identity and zero where the reference
    camera's file leaves them out)."""
    eye = np.eye(3).ravel()
    rotation = [_number(section, f"R_{k}", path, None if required else eye[k]) for k in range(9)]
    translation = [_number(section, f"T_{k}", path, None if required else 0.0) for k in range(3)]
    return np.reshape(rotation, (3, 3)), np.asarray(translation)


def camera_json_from_davinci(path: str | Path, width: int, height: int) -> dict:
    """camera.json's content, with its `"stereo"` block, from a da Vinci's
    `StereoCalibration.ini`, for frames `width` x `height` px (one camera's image in the
    video); each error names the file, the section and the key."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: calibration file not found")
    parser = configparser.ConfigParser()
    parser.optionxform = str  # keys as written: fc_x, R_0
    try:
        parser.read(path, encoding="utf-8")
    except (configparser.Error, UnicodeDecodeError) as error:
        reason = str(error).splitlines()[0][:200]
        raise CaptureError(f"{path}: not a da Vinci calibration file ({reason})") from None
    missing = [name for name in _SECTIONS if name not in parser]
    if missing:
        raise CaptureError(
            f"{path}: no [{'] or ['.join(missing)}] section (a da Vinci's StereoCalibration.ini "
            "has [StereoLeft] and [StereoRight])"
        )
    left, right = parser["StereoLeft"], parser["StereoRight"]
    calibrated = (_number(left, "res_x", path, width), _number(left, "res_y", path, height))
    scale = width / calibrated[0]
    if abs(height / calibrated[1] - scale) > 0.01 * scale:
        aspect = (width / height) / (calibrated[0] / calibrated[1])
        flag = {2: "--side-by-side", 0.5: "--top-bottom"}.get(round(aspect * 2) / 2)
        raise CaptureError(
            f"{path}: calibrated for {calibrated[0]:g}x{calibrated[1]:g} images, the video's "
            f"are {width}x{height} ("
            + (f"two cameras' images in each frame? {flag})" if flag else "another aspect)")
        )
    size = (int(width), int(height))
    described = _camera(left, path, size, scale)
    left_camera = camera_from_json(described, path)
    left_rotation, left_translation = _pose(left, path, required=False)
    right_rotation, right_translation = _pose(right, path, required=True)
    rotation = right_rotation @ left_rotation.T
    stereo = {
        "right": _camera(right, path, size, scale),
        "R": rotation.tolist(),
        "T": (right_translation - rotation @ left_translation).tolist(),
    }
    parse_stereo(stereo, left_camera, str(path), camera_from_json)  # checked as camera.json's
    return {**described, "stereo": stereo}
