"""Near-white that the camera turned grey: read as clipped.

A camera's processing desaturates what is close to its white: where a channel nears full
scale it pulls the others up to it, so a bright pixel of red mucosa is written grey. The
shared sinus frames show it: 0.38% of their pixels have all three channels within one code
value of each other at 225-239 of 255 (median 228), never the tissue's colour, while
coloured pixels reach 255. No rule at full scale calls them clipped, yet their values are
not the light's in any channel (the red one lost what the others gained): counted as
observations, these 0.2% of a 640 px capture's pixels held half the squared error of
Lambert's model on the sinus's held-out frames (12 frames: 25.4 -> 17.8 levels RMS without
them; docs/real-video.md).

So a frame's pixels whose channels agree within `GREY_CODES` code values at `BRIGHT` of
full scale or above (and below it: at full scale a pixel is clipped already) read as
clipped (every channel 1.0), as a clipped pixel does for every
estimator, in a frame whose bright pixels are coloured (their median chroma, (max - min)
/ max, at least `COLOURED`): a grey scene's grey is its colour, not the camera's. The
left frames get the rule in `load_capture`, a stereo capture's right images in
`Capture.right_image`.
"""

import numpy as np

# Channels within this many code values (8-bit; 16-bit scaled) are grey.
GREY_CODES = 1
# ...at or above this share of full scale: 188 of 255, 0.5 in linear light under sRGB.
BRIGHT = 188 / 255
# A frame's bright pixels are coloured where their median chroma is at least this.
COLOURED = 0.1


def desaturated(raw: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of a recorded frame (uint8 or uint16, (H, W, 3)) that the
    camera turned grey near its white (the module doc); none in a grey scene."""
    top, step = (255, 1) if raw.dtype == np.uint8 else (65535, 257)
    brightest = raw.max(axis=-1).astype(np.int64)
    spread = brightest - raw.min(axis=-1)
    bright = brightest >= BRIGHT * top
    grey = bright & (spread <= GREY_CODES * step) & (brightest < top)  # full scale: clipped
    if not grey.any():
        return grey
    chroma = spread[bright] / brightest[bright]
    return grey if np.median(chroma) >= COLOURED else np.zeros(grey.shape, bool)
