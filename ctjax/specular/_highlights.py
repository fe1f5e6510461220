"""Specular highlights: which pixels of a frame are S (paper section 6, step 2).

A highlight adds the light's colour (near white) to the tissue's: under the dichromatic
model a pixel is `I = D + s (1, 1, 1)`, `D` the diffuse colour of the tissue there. Two
rules find S; both take linear RGB in [0, 1] (H, W, 3) and the `visible` (H, W) pixels.

- `WhiterThanTissue` (the default), after Arnold et al. (2010, "Automatic segmentation and
  inpainting of specular highlights for endoscopic imaging", EURASIP J. Image Video Process.):
  a highlight is judged against the *local* tissue, not against fixed thresholds, so it
  works on bright, dim and red-clipped frames alike. With `r = min / max` a pixel's least
  to greatest channel ratio (shading scales `D` and keeps `r`; only added white raises it),
  its *whiteness* against a tissue colour `B` of ratio `r_B` is `(r - r_B) / (1 - r_B)`:
  the share of its brightest channel that is added white (0.5: the added white equals the
  tissue's own light in that channel).

  The tissue colour `B` is a median over a window of `window` times the image's width (on
  a copy at most 256 px wide: a highlight smaller than half the window does not move it)
  in which every pixel votes but the *white* ones (`r >= white`, brighter than the frame's
  median: white is not a tissue colour, and a white core larger than the window would
  otherwise be its own surroundings) and those of the field of view's rim (below); where
  a whole cell of the copy is left out or out of view, it takes the colour of the nearest
  tissue (the frame's median, redder than a pale wall, would make the wall beside the
  border look whiter than its surroundings). Pale tissue (a sinus wall close to
  the scope, fat, a gallbladder) therefore votes in its own surroundings and is not
  whiter than itself. (An earlier version left every pale, bright pixel out of the median
  and compared pale walls with the red tissue beyond them: on real sinus video S was 12%
  of the field of view, 18x the area of the near-white cores, `benchmarks/masks_real.py`.)

  S is grown from seeds (hysteresis, as in highlight segmentation since Arnold et al.):
  a pixel is a *seed* when
  1. it is near white in its own colour (`r >= near_white`), at least as bright as the
     frame's median in its brightest channel, whiter than `B` by at least `whiteness`,
     and its luminance at least `contrast` times `B`'s; or
  2. near white and bright as in 1, whiter by `whiteness` than the tissue over a wide
     window (`wide_window`, the same median), and its brightest channel at least
     `outshine` times that tissue's: a broad highlight (larger than `window`, its own
     surroundings there) on darker tissue. Added light raises every channel; a paler
     tissue raises the others, not the brightest much. (Added white equal to the tissue's
     own light doubles its brightest channel; 1.5 leaves room for the light's falloff
     across the wide window); or
  3. it is clipped (Arnold's first module, absolute): every channel at least `clip_level`,
     or its brightest channel clipped with `r >= 1 - clip_chroma` and whiter than `B` (a
     tinted clipped core: on red tissue the red clips first).
  S is then every pixel connected (8-neighbourhood) to a seed through *skirt* pixels: bright,
  and passing test 1 with both bars lowered to `grow` of theirs (whiteness at least
  `grow * whiteness`, luminance at least `1 + grow * (contrast - 1)` times `B`'s): the skirt
  of a highlight, and the tinted edge of a clipped core whose other channels stopped short
  of the clip, without any pale tissue that holds no seed.
  Last, an S component lying mostly within `rim` times the image's width of the field of
  view's edge is dropped: the bright rim of the image circle is light reflected inside the
  scope, not tissue (the image's own edges do not count: a cropped frame has none). That
  band is no reference for the tissue colour either: bright or vignetted, it is the lens's.
  Limits: a white object (gauze, a bright instrument) is whiter than the tissue around it
  too, and is taken as S (unless the capture excludes its pixels: `ctjax.io._excluded`).
  A broad, soft white patch where a wall close to the scope overexposes is taken as S
  whole, whether or not its values reach the top of the range.
  A soft lobe whose added white stays below the tissue's own light (whiteness under
  `whiteness` at its peak, e.g. one whose red clipped first on bright red tissue) and
  that is larger than `window` gives no seed, and is not S unless it touches one.
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
from .._tissue import SUBSAMPLE, channel_max, channel_min, local_tissues, luminance


class HighlightRule(Protocol):
    """What decides S: `rule(image, visible) -> (H, W) bool`. A frozen dataclass whose
    fields are the rule's parameters, so that options print and compare."""

    def __call__(self, image: np.ndarray, visible: np.ndarray) -> np.ndarray: ...


def _fraction(name: str, value: float, low: float = 0.0, high: float = 1.0) -> None:
    if not np.isfinite(value) or not low <= value <= high:
        raise ParameterError(f"{name} must be in [{low:g}, {high:g}], got {value}")


# White pixels are left out of the tissue median with a margin of this many pixels (their
# fringe of blur and compression).
_WHITE_MARGIN_PX = 2


@dataclasses.dataclass(frozen=True)
class WhiterThanTissue:
    """Seeds whiter and brighter than the local tissue (or clipped), grown into their
    whitish skirt; the field of view's bright rim left out (see the module doc)."""

    whiteness: float = 0.5
    near_white: float = 0.6
    contrast: float = 1.15
    clip_level: float = 0.98
    clip_chroma: float = 0.3
    window: float = 1 / 12
    white: float = 0.9
    outshine: float = 1.5
    wide_window: float = 1 / 4
    grow: float = 2 / 3
    rim: float = 0.006

    def __str__(self) -> str:  # in messages: the command line's words
        return f"--highlights whiter (--whiteness {self.whiteness:g}, --contrast {self.contrast:g})"

    def __post_init__(self):
        for name in ("whiteness", "near_white", "clip_level", "clip_chroma", "white"):
            _fraction(name, getattr(self, name))
        _fraction("grow", self.grow)
        _fraction("window", self.window, 1e-3, 1.0)
        _fraction("wide_window", self.wide_window, 1e-3, 1.0)
        _fraction("rim", self.rim, 0.0, 0.5)
        for name in ("contrast", "outshine"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ParameterError(f"{name} must be positive, got {value}")

    def __call__(self, image: np.ndarray, visible: np.ndarray) -> np.ndarray:
        if not visible.any():
            return np.zeros(visible.shape, bool)
        brightest, least = channel_max(image), channel_min(image)
        ratio = least / np.maximum(brightest, 1e-6)
        bright = visible & (brightest >= np.median(brightest[visible][::SUBSAMPLE]))
        # White is not a tissue colour: white pixels (and their fringe) do not vote.
        white = (bright & (ratio >= self.white)).astype(np.uint8)
        side = 2 * _WHITE_MARGIN_PX + 1
        white = cv2.dilate(white, np.ones((side, side), np.uint8)).astype(bool)
        # Nor does the field of view's rim (the lens's bright or dim edge).
        rim = _rim_band(visible, self.rim)
        reference = visible & ~white & ~rim
        tissue, wide = local_tissues(
            image, reference, (self.window, self.wide_window), fill="nearest"
        )
        whiteness = _whiteness(ratio, tissue)
        light = luminance(image)
        tissue_light = luminance(tissue)
        near_white = bright & (ratio >= self.near_white)
        local = near_white & (whiteness >= self.whiteness) & (light >= self.contrast * tissue_light)
        broad = (
            near_white
            & (_whiteness(ratio, wide) >= self.whiteness)
            & (brightest >= self.outshine * channel_max(wide))
        )
        white_clip = least >= self.clip_level
        tinted_clip = (
            (brightest >= self.clip_level)
            & (ratio >= 1 - self.clip_chroma)
            & (whiteness >= self.whiteness)
        )
        seeds = visible & (local | broad | white_clip | tinted_clip)
        if not seeds.any():
            return seeds
        # The skirt: both of the seeds' bars lowered to `grow` of theirs.
        skirt = (
            bright
            & (whiteness >= self.grow * self.whiteness)
            & (light >= (1 + self.grow * (self.contrast - 1)) * tissue_light)
        )
        specular = _grown(seeds, skirt)
        return _off_the_rim(specular, rim)


def _whiteness(ratio: np.ndarray, tissue: np.ndarray) -> np.ndarray:
    """(H, W): the share of each pixel's brightest channel that is added white, from its
    least-to-greatest ratio against the tissue's (capped at 0.95: white tissue is no
    reference)."""
    tissue_ratio = channel_min(tissue) / np.maximum(channel_max(tissue), 1e-6)
    tissue_ratio = np.minimum(tissue_ratio, 0.95)
    return (ratio - tissue_ratio) / (1 - tissue_ratio)


def _grown(seeds: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """The connected components (8-neighbourhood) of `seeds | allowed` holding a seed."""
    count, labels = cv2.connectedComponents((seeds | allowed).astype(np.uint8), connectivity=8)
    keep = np.zeros(count, bool)
    keep[labels[seeds]] = True
    keep[0] = False
    return keep[labels]


def _rim_band(visible: np.ndarray, rim: float) -> np.ndarray:
    """(H, W): the pixels of `visible` within `rim` times the image's width of its edge
    (not of the image's edge: a cropped frame has no rim)."""
    width_px = rim * visible.shape[1]
    if width_px <= 0 or visible.all():
        return np.zeros(visible.shape, bool)
    inside = np.pad(visible.astype(np.uint8), 1, constant_values=1)
    distance = cv2.distanceTransform(inside, cv2.DIST_L2, 5)[1:-1, 1:-1]
    return visible & (distance <= width_px)


def _off_the_rim(mask: np.ndarray, rim: np.ndarray) -> np.ndarray:
    """`mask` less its components lying mostly (at least half their pixels) in `rim`."""
    band = mask & rim
    if not band.any():
        return mask
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), 8)
    on_rim = np.bincount(labels[band], minlength=count) >= 0.5 * stats[:, cv2.CC_STAT_AREA]
    on_rim[0] = False
    return mask & ~on_rim[labels]


@dataclasses.dataclass(frozen=True)
class HLSThresholds:
    """The paper's rule: HLS lightness >= `lightness` and saturation <= `saturation`."""

    lightness: float = 0.95
    saturation: float = 0.05

    def __post_init__(self):
        _fraction("lightness", self.lightness)
        _fraction("saturation", self.saturation)

    def __str__(self) -> str:  # in messages: the command line's words
        return (
            f"--highlights hls (--lightness {self.lightness:g}, --saturation {self.saturation:g})"
        )

    def __call__(self, image: np.ndarray, visible: np.ndarray) -> np.ndarray:
        hls = cv2.cvtColor(np.ascontiguousarray(image, np.float32), cv2.COLOR_RGB2HLS)
        return visible & (hls[..., 1] >= self.lightness) & (hls[..., 2] <= self.saturation)
