"""A channel that stops following the others below full scale: read as clipped there.

A camera clips each channel of its sensor at full scale, and then processes the three: a
white balance gain under one and a colour matrix move a clipped channel's top below the
file's full scale, and a knee rounds it. Such a channel tops out at a ceiling of its own
while the others still rise. The shared sinus frames show it in red: against the mean of
green and blue, red rises 1.5 codes per code up to about 210 of 255 and then 0.1 to 0.2
codes per code while the others climb another 110 codes (the red of 43% of the frames'
pixels sits there, R 208-228 at G 100-220). No rule at full scale calls those values
clipped, yet they are not the light's in red: a fit reads the brighter half of the frames
as flatter than Lambert in red and its lobe as green and blue only (F_tilde [0, 0.013,
0.016]), and those red values held most of the fit's squared error (RGB RMSE 20.1 levels
with them, 7.2 without; docs/real-video.md).

So a capture's frames are sampled (every `STEP`-th pixel of each, without the dark ones and
those already clipped or turned grey) and, for each channel, its median is taken against
the mean of the other two in bins of `BIN` of full scale. Two lines meeting at a knot (a
hinge, the knot at the bin that fits best) are fitted to those medians by least squares,
each bin weighted by the square root of its samples. The channel has a ceiling where the
second line is a plateau: it rises at most `PLATEAU_SLOPE` codes per code of the others,
over at least `PLATEAU_SPAN` of full scale up to the brightest bin, the first rises at
least `KNEE_RATIO` times as fast, and the knot lies at `BRIGHT` of full scale or above and
below `BELOW_FULL_SCALE` (there: the sensor's own clipping, the full-scale values left out
of the samples). The channel's values at or above the knot's level read as clipped
(`Capture.saturation`: the estimators' observations leave them out; the images keep them,
as recorded). The sinus's red: a knot at 202-203 of 255 (12 frames at 640 px, all 35 at
full size). The cholecystectomy video's red (rising 1 code per code up to 236, then to 253
next to full scale) and a da Vinci's channels (rising to full scale, SCARED) have none;
nor has any channel of a synthetic capture.
"""

import numpy as np

# Every STEP-th pixel of each frame, in both directions, is sampled...
STEP = 4
# ...where its brightest channel reaches this share of full scale.
DARK = 1 / 8
# The bins of the other channels' mean, as a share of full scale (16 codes of 255).
BIN = 16 / 255
# A bin counts with at least this many samples...
MIN_SAMPLES = 200
# ...of at most this many (an even stride through a long capture's).
MAX_SAMPLES = 500_000
# The plateau: its line rises at most this many codes per code of the others...
PLATEAU_SLOPE = 0.25
# ...over at least this share of full scale of the others' mean, up to the brightest bin...
PLATEAU_SPAN = 0.25
# ...the line before it rises at least this many times as fast (and 0.2 codes per code)...
KNEE_RATIO = 4.0
# ...and the knot lies at this share of full scale or above (a ceiling is near the top),
BRIGHT = 0.5
# ...but below this one: a plateau just under full scale is the sensor's own clipping, the
# values next to it spread by noise and compression below the full-scale samples left out.
BELOW_FULL_SCALE = 0.95


def samples_of(raw: np.ndarray, clipped: np.ndarray) -> np.ndarray:
    """(N, 3) codes of a recorded frame ((H, W, 3) uint8 or uint16): every `STEP`-th pixel
    that is not `clipped` ((H, W) bool: turned grey), has no channel at full scale and is
    not dark (a channel at `DARK` of full scale or above: black borders and shadows would
    tie the first line to black)."""
    top = np.iinfo(raw.dtype).max
    part = raw[::STEP, ::STEP].reshape(-1, raw.shape[-1])
    brightest = part.max(axis=-1)
    keep = ~clipped[::STEP, ::STEP].reshape(-1) & (brightest < top) & (brightest >= DARK * top)
    return part[keep]


def channel_profile(samples: np.ndarray, top: int, channel: int):
    """One channel's medians against the other channels' mean: the bins' centres (codes of
    the others' mean), the channel's median in each and each bin's weight (the root of its
    samples), over the bins with at least `MIN_SAMPLES` (an even stride through at most
    `MAX_SAMPLES` of `samples`, (N, 3) codes)."""
    codes = samples[:: max(1, -(-len(samples) // MAX_SAMPLES))].astype(np.float64)
    width = BIN * top
    others = np.delete(codes, channel, axis=-1).mean(axis=-1)
    index = np.floor(others / width).astype(int)
    order = np.lexsort((codes[:, channel], index))  # by bin, then by the channel's value
    bins, starts, counts = np.unique(index[order], return_index=True, return_counts=True)
    full = counts >= MIN_SAMPLES
    ordered = codes[order, channel]
    medians = [
        np.median(ordered[a : a + n]) for a, n in zip(starts[full], counts[full], strict=True)
    ]
    return (bins[full] + 0.5) * width, np.array(medians), np.sqrt(counts[full])


def channel_ceilings(samples: np.ndarray, top: int) -> list[int | None]:
    """Per channel, the code value from which it reads as clipped, or None where it follows
    the others up to the brightest samples (the module doc). `samples`: (N, 3) codes."""
    return [_ceiling(*channel_profile(samples, top, c), top) for c in range(samples.shape[-1])]


def hinge(centres, medians, weights) -> tuple[int, float, float, float] | None:
    """Two lines meeting at a knot, fitted by least squares to the bins' medians weighted by
    `weights`, the knot at the bin that fits best: (the knot's bin, its level, the first
    line's slope, the second's), or None with under 5 bins."""
    best = None
    for k in range(2, len(centres) - 2):
        design = np.stack(
            [np.ones_like(centres), centres, np.maximum(centres - centres[k], 0)], axis=-1
        )
        coef, residual, *_ = np.linalg.lstsq(
            design * weights[:, None], medians * weights, rcond=None
        )
        cost = residual[0] if len(residual) else 0.0
        if best is None or cost < best[0]:
            best = (cost, k, coef)
    if best is None:
        return None
    _, k, (offset, slope, change) = best
    return k, float(offset + slope * centres[k]), float(slope), float(slope + change)


def _ceiling(centres, medians, weights, top: int) -> int | None:
    """The hinge's level where its second line is a plateau (the module doc), or None."""
    fitted = hinge(centres, medians, weights)
    if fitted is None:
        return None
    k, level, slope, plateau = fitted
    if (
        BRIGHT * top <= level < BELOW_FULL_SCALE * top
        and centres[-1] - centres[k] >= PLATEAU_SPAN * top
        and plateau <= PLATEAU_SLOPE
        and slope >= KNEE_RATIO * max(plateau, 0.05)
    ):
        return int(np.ceil(level))
    return None
