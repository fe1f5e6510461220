"""Specular highlights: which pixels of a frame are S (paper section 6, step 2).

A highlight adds the light's colour (near white) to the tissue's: under the dichromatic
model a pixel is `I = D + s (1, 1, 1)`, `D` the diffuse colour of the tissue there. Two
rules find S; both take linear RGB in [0, 1] (H, W, 3) and the `visible` (H, W) pixels.

- `WhiterThanTissue` (the default), after Arnold et al. (2010, "Automatic segmentation and
  inpainting of specular highlights for endoscopic imaging", EURASIP J. Image Video Process.):
  a highlight is judged against the *local* tissue, not against fixed thresholds, so it
  works on bright, dim and red-clipped frames alike. The local tissue colour `B` is a
  median filter over a window of `window` times the image's width (on a copy at most 256 px
  wide: a highlight smaller than half the window does not move the median). A pixel is
  in S when it is
  1. *whiter than the tissue around it*: its least-to-greatest channel ratio `r = min/max`
     has moved at least `whiteness` of the way from the local tissue's ratio `r_B` to white
     (1): `(r - r_B) / (1 - r_B) >= whiteness`. Shading scales `D` and keeps `r`; only an
     added white component raises it. A pale patch of fat is whiter than red tissue but
     not this much whiter;
  2. *near white*: `r >= near_white`, the pixel's own colour within a tint of white;
  3. *brighter than the tissue around it*: luminance at least `contrast` times `B`'s, and its
     brightest channel at least the frame's median (out of the dark noise floor);
  or it is *clipped* (Arnold's first module, absolute): every channel at least `clip_level`,
  or its brightest channel clipped with `r >= 1 - clip_chroma` and whiter than the tissue
  around it (a tinted clipped core; on red tissue the red clips first, and clipping alone
  whitens a pale patch: hence the local test). Pixels of conditions 2-3 (candidates) are
  left out of the median, as Arnold et al. inpaint them before filtering (a highlight
  larger than the window would otherwise be its own surroundings). Limit: a white object
  (gauze, a bright instrument) is whiter than the tissue around it too, and is taken as S.
- `HLSThresholds`, the paper's rule: HLS lightness >= 0.95 and saturation <= 0.05. HLS
  saturation is (max - min) / (2 - max - min) above lightness 0.5: near white it divides by
  almost 0, so a clipped core with any tint never passes; kept for the paper's figures.

Specks smaller than `min_speck_px` pixels (connected, 8-neighbourhood) are removed by the
caller: isolated bright noise is not a highlight.
"""

import dataclasses
from typing import Protocol

import cv2
import numpy as np

from .._errors import ParameterError
from .._tissue import SUBSAMPLE, channel_max, channel_min, local_tissue, luminance


class HighlightRule(Protocol):
    """What decides S: `rule(image, visible) -> (H, W) bool`. A frozen dataclass whose
    fields are the rule's parameters, so that options print and compare."""

    def __call__(self, image: np.ndarray, visible: np.ndarray) -> np.ndarray: ...


def _fraction(name: str, value: float, low: float = 0.0, high: float = 1.0) -> None:
    if not np.isfinite(value) or not low <= value <= high:
        raise ParameterError(f"{name} must be in [{low:g}, {high:g}], got {value}")


@dataclasses.dataclass(frozen=True)
class WhiterThanTissue:
    """Bright and whiter than the local tissue, or clipped (see the module doc)."""

    whiteness: float = 0.5
    near_white: float = 0.6
    contrast: float = 1.15
    clip_level: float = 0.98
    clip_chroma: float = 0.3
    window: float = 1 / 12

    def __post_init__(self):
        for name in ("whiteness", "near_white", "clip_level", "clip_chroma"):
            _fraction(name, getattr(self, name))
        _fraction("window", self.window, 1e-3, 1.0)
        if not np.isfinite(self.contrast) or self.contrast <= 0:
            raise ParameterError(f"contrast must be positive, got {self.contrast}")

    def __call__(self, image: np.ndarray, visible: np.ndarray) -> np.ndarray:
        if not visible.any():
            return np.zeros(visible.shape, bool)
        brightest, least = channel_max(image), channel_min(image)
        ratio = least / np.maximum(brightest, 1e-6)
        bright = brightest >= np.median(brightest[visible][::SUBSAMPLE])
        candidate = visible & bright & (ratio >= self.near_white)
        # The tissue around a highlight, not the highlight: candidates do not vote.
        tissue = local_tissue(image, visible & ~candidate, self.window)
        tissue_ratio = np.minimum(channel_min(tissue) / np.maximum(channel_max(tissue), 1e-6), 0.95)
        whiter = (ratio - tissue_ratio) >= self.whiteness * (1 - tissue_ratio)
        brighter = luminance(image) >= self.contrast * luminance(tissue)
        white_clip = least >= self.clip_level
        tinted_clip = (brightest >= self.clip_level) & (ratio >= 1 - self.clip_chroma) & whiter
        return visible & (white_clip | tinted_clip | (candidate & whiter & brighter))


@dataclasses.dataclass(frozen=True)
class HLSThresholds:
    """The paper's rule: HLS lightness >= `lightness` and saturation <= `saturation`."""

    lightness: float = 0.95
    saturation: float = 0.05

    def __post_init__(self):
        _fraction("lightness", self.lightness)
        _fraction("saturation", self.saturation)

    def __call__(self, image: np.ndarray, visible: np.ndarray) -> np.ndarray:
        hls = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2HLS)
        return visible & (hls[..., 1] >= self.lightness) & (hls[..., 2] <= self.saturation)
