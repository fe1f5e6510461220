"""S, S~ and the clipped pixels of every frame of a capture, and how they are found."""

import dataclasses

import numpy as np

from .._errors import CtjaxError
from .._threads import default_workers, in_order
from .._tissue import channel_max
from ..io import Capture
from ._highlights import HighlightRule
from ._specular_set import (
    DEFAULT_HIGHLIGHTS,
    DEFAULT_MIN_SPECK_PX,
    DEFAULT_RING_PX,
    SpecularSets,
    specular_sets,
)


@dataclasses.dataclass(frozen=True)
class MaskOptions:
    """How S and S~ are found: the `highlights` rule (`WhiterThanTissue` by default,
    `HLSThresholds` the paper's), the ring's width and the smallest speck kept."""

    highlights: HighlightRule = DEFAULT_HIGHLIGHTS
    ring_px: float = DEFAULT_RING_PX
    min_speck_px: int = DEFAULT_MIN_SPECK_PX


def capture_sets(capture: Capture, options: MaskOptions = MaskOptions()) -> list[SpecularSets]:
    """S, S~ and the clipped channels of every frame (pixels outside the frame's field of
    view excluded, and from the ring those without a normal, when the frame has a shape).

    Raises `CtjaxError` for a frame whose every pixel is saturated (nothing to fit).
    """
    for frame in capture.frames:
        if np.all(channel_max(frame.image) >= 1.0):
            raise CtjaxError(
                f"{capture.root}: frame {frame.name}: every pixel is saturated (at full scale); "
                "an over-exposed image carries no shading"
            )

    def sets_of(frame):
        return specular_sets(
            frame.image,
            # Without a shape (images only), the ring is where the fit will look once the
            # shape is reconstructed.
            frame.geometry_mask if frame.has_geometry else frame.visible,
            highlights=options.highlights,
            ring_px=options.ring_px,
            min_speck_px=options.min_speck_px,
            saturation_level=np.asarray(capture.saturation),
            visible=frame.visible,
        )

    # The frames on threads (OpenCV and NumPy release the GIL): the same sets, sooner.
    return list(in_order(sets_of, capture.frames, default_workers()))
