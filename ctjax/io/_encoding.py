"""How a capture's images encode light: the camera's response, undone on load.

Every estimator in ctjax works on linear intensity (twice the light, twice the value): the
paper's model is a sum of lobes, and a sum survives only in linear units. Recorded images
rarely are linear: video and JPEG frames, and most 8-bit PNGs, are sRGB-encoded (IEC
61966-2-1: a linear toe, then a 1/2.4 power), a curve every camera pipeline applies before
compression. Read as linear, an encoded frame flattens the shading's fall towards grazing
angles and lifts dim tissue, which a fit then explains with a broad lobe (on real frames
sigma went to the top of its range; decoded, it came inside it).

`camera.json`'s optional `"encoding"` says which: `"srgb"` or `"linear"`. Without it, 8-bit
images (and JPEGs) are taken as sRGB, with a note, and 16-bit images as linear (a 16-bit
frame is a raw or a rendering more often than a video). Synthetic captures are written
`"linear"`, imported videos `"srgb"`.

Full scale maps to full scale (decode(1) = 1 exactly), so a clipped channel stays at 1.0
and every "at the sensor's maximum" test reads the same in either encoding.
"""

import numpy as np

from .._errors import CaptureError

SRGB = "srgb"
LINEAR = "linear"
ENCODINGS = (SRGB, LINEAR)


def srgb_to_linear(encoded: np.ndarray) -> np.ndarray:
    """The sRGB decoding curve (IEC 61966-2-1) of values in [0, 1]."""
    e = np.asarray(encoded)
    dtype = e.dtype if np.issubdtype(e.dtype, np.floating) else np.float64
    e = e.astype(dtype, copy=False)
    toe = e <= 0.04045
    return np.where(toe, e / 12.92, ((np.maximum(e, 0.04045) + 0.055) / 1.055) ** 2.4).astype(
        dtype, copy=False
    )


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """The sRGB encoding curve of linear values in [0, 1] (the inverse of `srgb_to_linear`)."""
    x = np.asarray(linear)
    dtype = x.dtype if np.issubdtype(x.dtype, np.floating) else np.float64
    x = np.clip(x.astype(dtype, copy=False), 0, None)
    toe = x <= 0.0031308
    power = 1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055
    return np.where(toe, 12.92 * x, power).astype(dtype, copy=False)


# 8-bit levels decoded once: a lookup per pixel instead of a power.
_SRGB_8BIT = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)


def decode(raw: np.ndarray, encoding: str) -> np.ndarray:
    """Recorded integer pixels (uint8 or uint16) as float32 linear intensity in [0, 1]."""
    top = 255.0 if raw.dtype == np.uint8 else 65535.0
    if encoding == LINEAR:
        return raw.astype(np.float32) / np.float32(top)
    if raw.dtype == np.uint8:
        return _SRGB_8BIT[raw]
    return srgb_to_linear(raw.astype(np.float32) / np.float32(top))


def encode(linear: np.ndarray, encoding: str) -> np.ndarray:
    """Linear intensity as the recorded values in [0, 1] of `encoding` (before
    quantisation): what a camera with that response writes."""
    linear = np.asarray(linear)
    return linear_to_srgb(linear) if encoding == SRGB else linear


def declared_encoding(data: dict, where: str) -> str | None:
    """`camera.json`'s `"encoding"`, validated; None where it is not given."""
    if "encoding" not in data:
        return None
    value = data["encoding"]
    if not isinstance(value, str) or value.lower() not in ENCODINGS:
        raise CaptureError(
            f"{where}: encoding must be one of {', '.join(map(repr, ENCODINGS))}, got {value!r}"
        )
    return value.lower()


def default_encoding(bits: int) -> str:
    """The encoding of images whose capture does not say: sRGB for 8 bits, linear for 16."""
    return SRGB if bits == 8 else LINEAR
