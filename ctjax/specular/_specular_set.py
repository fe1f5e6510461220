"""The specular set S and its ring S~ (paper section 6, steps 2-3), with OpenCV.

S: the highlights, found by a `HighlightRule` (default `WhiterThanTissue`: bright and whiter
than the local tissue, or clipped; `HLSThresholds` is the paper's ".95" rule; see
`ctjax.specular._highlights`). S~: non-specular pixels within `ring_px` (paper: 3) of the
specular frontier, found with a distance transform, with a valid normal and no channel at
the sensor's maximum. Clipping is per channel (`SpecularSets.clipped`): a channel at full
scale records "at least this bright", which the model cannot predict (on red tissue the red
clips first, and the green and blue of the same pixel are still measurements). A channel
at its ceiling below full scale (`Capture.saturation`: where it stops following the others,
or the camera's white) is clipped the same way, and S's rule sees it at full scale: an
overexposed patch at a camera's white of 238 of 255 is S whole, as one at 255 is.
"""

import dataclasses

import cv2
import numpy as np

from .._errors import ParameterError
from ._highlights import HighlightRule, WhiterThanTissue

DEFAULT_HIGHLIGHTS = WhiterThanTissue()
DEFAULT_RING_PX = 3
DEFAULT_MIN_SPECK_PX = 3


@dataclasses.dataclass(frozen=True)
class SpecularSets:
    """Masks of one frame: (H, W) booleans, and `clipped` (H, W, 3) per channel."""

    specular: np.ndarray  # S
    ring: np.ndarray  # S~
    clipped: np.ndarray  # (H, W, 3): the channel at the sensor's maximum, outside S

    @property
    def saturated(self) -> np.ndarray:
        """(H, W): pixels outside S with at least one clipped channel."""
        return np.any(self.clipped, axis=-1)

    @property
    def non_specular(self) -> np.ndarray:
        """S-bar: every pixel that is neither specular nor saturated."""
        return ~self.specular & ~self.saturated


def specular_mask(
    image: np.ndarray,
    highlights: HighlightRule = DEFAULT_HIGHLIGHTS,
    min_speck_px: int = DEFAULT_MIN_SPECK_PX,
    visible: np.ndarray | None = None,
) -> np.ndarray:
    """S: the pixels of `visible` (default: all) that `highlights` finds.

    `image` is linear RGB in [0, 1], (H, W, 3). Connected specks smaller than `min_speck_px`
    pixels are removed (0 keeps everything): isolated bright noise is not a highlight.
    """
    _check_image(image)
    if int(min_speck_px) != min_speck_px or min_speck_px < 0:
        raise ParameterError(f"min_speck_px must be a non-negative integer, got {min_speck_px}")
    visible = _check_mask("visible", visible, image, default=True)
    mask = highlights(np.asarray(image, np.float32), visible)
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
    highlights: HighlightRule = DEFAULT_HIGHLIGHTS,
    ring_px: float = DEFAULT_RING_PX,
    min_speck_px: int = DEFAULT_MIN_SPECK_PX,
    saturation_level=1.0,
    visible: np.ndarray | None = None,
) -> SpecularSets:
    """S, S~ and the clipped channels of one frame.

    `valid` (H, W) marks pixels with a valid normal (default: all). The ring holds the
    non-specular, valid pixels whose distance to the nearest specular pixel is at most
    `ring_px` (Euclidean, in pixels) with every channel below `saturation_level` (one level,
    or one per channel: `Capture.saturation`, the camera's ceilings).
    `visible` (H, W): the scene (the endoscope's field of view, off overlays; default:
    all): nothing outside it is in any set.
    """
    _check_image(image)
    if not np.isfinite(ring_px) or ring_px <= 0:
        raise ParameterError(f"ring_px must be positive, got {ring_px}")
    ring_px = min(float(ring_px), float(np.hypot(*image.shape[:2])))  # wider: the same ring
    visible = _check_mask("visible", visible, image, default=True)
    valid = _check_mask("valid", valid, image, default=True)
    at_ceiling = image >= saturation_level
    # The rule reads a channel at its ceiling as at full scale: clipped, as it is (a camera
    # whose white lies below full scale clips there; `ctjax.io._channel_ceiling`).
    seen = np.where(at_ceiling, np.float32(1.0), image) if np.any(at_ceiling) else image
    specular = specular_mask(seen, highlights, min_speck_px, visible)
    clipped = at_ceiling & (~specular & visible)[..., None]
    if specular.any():
        distance = cv2.distanceTransform(
            (~specular).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE
        )
        measured = ~np.any(clipped, axis=-1)
        ring = (distance <= ring_px) & ~specular & measured & valid & visible
    else:
        ring = np.zeros_like(specular)
    return SpecularSets(specular, ring, clipped)


def _check_mask(name: str, mask, image: np.ndarray, *, default: bool) -> np.ndarray:
    if mask is None:
        return np.full(image.shape[:2], default)
    mask = np.asarray(mask)
    if mask.shape != image.shape[:2]:
        raise ParameterError(f"{name} mask has shape {mask.shape}, image {image.shape[:2]}")
    return mask.astype(bool, copy=False)


def _check_image(image: np.ndarray) -> None:
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ParameterError(f"image must be (H, W, 3) RGB, got shape {image.shape}")
    if not np.all(np.isfinite(image)):
        raise ParameterError("image has non-finite values")
