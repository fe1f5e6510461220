"""Reading and writing images: linear intensity in [0, 1], RGB order (OpenCV reads BGR).

Images are decoded from their recorded encoding (`ctjax.io._encoding`: sRGB or linear) on
read, and encoded on write."""

from pathlib import Path

import cv2
import numpy as np

from .._errors import CaptureError
from ._atomic import atomic_write_bytes
from ._encoding import ENCODINGS, LINEAR, decode, default_encoding, encode

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


def read_rgb(path: Path, encoding: str | None = None) -> np.ndarray:
    """An 8- or 16-bit RGB image as float32 (H, W, 3) linear intensity in [0, 1].

    `encoding`: how the file encodes light, `"srgb"` or `"linear"`; None: sRGB for 8-bit
    files, linear for 16-bit (`read_recorded` says which bit depth a file has)."""
    raw = read_recorded(path)
    if encoding is None:
        encoding = default_encoding(8 if raw.dtype == np.uint8 else 16)
    _check_encoding(encoding)
    return decode(raw, encoding)


def read_recorded(path: Path) -> np.ndarray:
    """An 8- or 16-bit RGB image's recorded values, (H, W, 3) uint8 or uint16, RGB order."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: image file not found")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.size == 0:
        raise CaptureError(f"{path}: cannot read image (truncated or not an image file)")
    if raw.ndim == 2 or (raw.ndim == 3 and raw.shape[2] == 1):
        raise CaptureError(f"{path}: grayscale image; ctjax needs RGB (3 channels)")
    if raw.shape[2] == 4:
        raise CaptureError(f"{path}: RGBA image (4 channels); save it as RGB without alpha")
    if raw.shape[2] != 3:
        raise CaptureError(f"{path}: image has {raw.shape[2]} channels; expected 3 (RGB)")
    if raw.dtype not in (np.uint8, np.uint16):
        raise CaptureError(f"{path}: {raw.dtype} pixels; expected 8- or 16-bit integers")
    return np.ascontiguousarray(raw[..., ::-1])


def _check_encoding(encoding: str) -> None:
    if encoding not in ENCODINGS:
        raise ValueError(f"encoding must be one of {ENCODINGS}, got {encoding!r}")


def write_rgb(path: Path, image: np.ndarray, bits: int = 8, encoding: str = LINEAR) -> None:
    """Write linear float RGB in [0, 1] (clipped) as an 8- or 16-bit PNG, atomically,
    encoded with `encoding` (`"linear"`: as it is; `"srgb"`: the sRGB curve)."""
    if bits not in (8, 16):
        raise ValueError(f"bits must be 8 or 16, got {bits}")
    _check_encoding(encoding)
    top = 255 if bits == 8 else 65535
    dtype = np.uint8 if bits == 8 else np.uint16
    recorded = encode(np.clip(np.asarray(image, np.float64), 0, 1), encoding)
    quantised = np.round(recorded * top).astype(dtype)
    write_quantised_rgb(path, quantised)


def write_quantised_rgb(path: Path, image: np.ndarray) -> None:
    """Write an already quantised uint8/uint16 RGB image as PNG, atomically."""
    path = Path(path)
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise CaptureError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, encoded.tobytes())


def write_mask(path: Path, mask: np.ndarray) -> None:
    """A boolean mask as an 8-bit PNG (255 where set), atomically: (H, W) grey, or
    (H, W, 3) one RGB channel per colour (e.g. the clipped channels)."""
    path = Path(path)
    pixels = np.where(mask, 255, 0).astype(np.uint8)
    if pixels.ndim == 3:
        pixels = np.ascontiguousarray(pixels[..., ::-1])  # OpenCV writes BGR
    ok, encoded = cv2.imencode(".png", pixels)
    if not ok:
        raise CaptureError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, encoded.tobytes())
