"""The specular set S and its ring S~ (paper section 6, steps 2-3), with OpenCV.

S: pixels that are bright and white, lightness >= 0.95 and saturation <= 0.05 in HLS (the
paper's ".95" thresholds). S~: non-specular pixels within `ring_px` (paper: 3) of the
specular frontier, found with a distance transform. Pixels without a valid normal, and
saturated non-specular pixels (a channel clipped, e.g. the red of a highlight's rim) are
excluded from the ring: their recorded value is not the model's.
"""

import dataclasses

import cv2
import numpy as np

from .._errors import ParameterError

DEFAULT_LIGHTNESS = 0.95
DEFAULT_SATURATION = 0.05
DEFAULT_RING_PX = 3
DEFAULT_MIN_SPECK_PX = 3


@dataclasses.dataclass(frozen=True)
class SpecularSets:
    """Boolean (H, W) masks of one frame."""

    specular: np.ndarray  # S
    ring: np.ndarray  # S~
    saturated: np.ndarray  # any channel at the sensor's maximum, outside S

    @property
    def non_specular(self) -> np.ndarray:
        """S-bar: every pixel that is neither specular nor saturated."""
        return ~self.specular & ~self.saturated


def specular_mask(
    image: np.ndarray,
    lightness: float = DEFAULT_LIGHTNESS,
    saturation: float = DEFAULT_SATURATION,
    min_speck_px: int = DEFAULT_MIN_SPECK_PX,
) -> np.ndarray:
    """S: pixels with HLS lightness >= `lightness` and saturation <= `saturation`.

    `image` is linear RGB in [0, 1], (H, W, 3). Connected specks smaller than `min_speck_px`
    pixels are removed (0 keeps everything): isolated bright noise is not a highlight.
    """
    _check_image(image)
    if not (0 <= lightness <= 1 and 0 <= saturation <= 1):
        raise ParameterError(
            f"lightness and saturation thresholds must be in [0, 1], got {lightness}, {saturation}"
        )
    if int(min_speck_px) != min_speck_px or min_speck_px < 0:
        raise ParameterError(f"min_speck_px must be a non-negative integer, got {min_speck_px}")
    hls = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2HLS)
    mask = (hls[..., 1] >= lightness) & (hls[..., 2] <= saturation)
    if min_speck_px > 1 and mask.any():
        _, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), 8)
        keep = stats[:, cv2.CC_STAT_AREA] >= min_speck_px
        keep[0] = False  # background
        mask = keep[labels]
    return mask


def specular_sets(
    image: np.ndarray,
    valid: np.ndarray | None = None,
    *,
    lightness: float = DEFAULT_LIGHTNESS,
    saturation: float = DEFAULT_SATURATION,
    ring_px: float = DEFAULT_RING_PX,
    min_speck_px: int = DEFAULT_MIN_SPECK_PX,
    saturation_level: float = 1.0,
    visible: np.ndarray | None = None,
) -> SpecularSets:
    """S, S~ and the saturated pixels of one frame.

    `valid` (H, W) marks pixels with a valid normal (default: all). The ring holds the
    non-specular, non-saturated, valid pixels whose distance to the nearest specular pixel is
    at most `ring_px` (Euclidean, in pixels). `visible` (H, W): the scene (the endoscope's
    field of view, off overlays; default: all): nothing outside it is in any set.
    """
    _check_image(image)
    if not np.isfinite(ring_px) or ring_px <= 0:
        raise ParameterError(f"ring_px must be positive, got {ring_px}")
    if visible is None:
        visible = np.ones(image.shape[:2], bool)
    elif visible.shape != image.shape[:2]:
        raise ParameterError(f"visible mask has shape {visible.shape}, image {image.shape[:2]}")
    specular = specular_mask(image, lightness, saturation, min_speck_px) & visible
    saturated = np.any(image >= saturation_level, axis=-1) & ~specular & visible
    if valid is None:
        valid = np.ones(specular.shape, bool)
    elif valid.shape != specular.shape:
        raise ParameterError(f"valid mask has shape {valid.shape}, image {specular.shape}")
    if specular.any():
        distance = cv2.distanceTransform(
            (~specular).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE
        )
        ring = (distance <= ring_px) & ~specular & ~saturated & valid & visible
    else:
        ring = np.zeros_like(specular)
    return SpecularSets(specular, ring, saturated)


def _check_image(image: np.ndarray) -> None:
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ParameterError(f"image must be (H, W, 3) RGB, got shape {image.shape}")
    if not np.all(np.isfinite(image)):
        raise ParameterError("image has non-finite values")
