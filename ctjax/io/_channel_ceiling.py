"""A channel that stops below full scale, or a camera white below it: read as clipped there.

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

A camera's white can lie below full scale too, in every channel at once: its processing
maps the sensor's clipped white to a grey short of the file's top (and a knee rounds what
leads there), so green and blue, not only red, pile up at one code and stop. Beside each
other, no channel stops following the others, and the hinge sees nothing. A second sinus
video of the same dataset shows it (`lppllppl920/DenseDescriptorLearning-Pytorch`, frames
2739-2834 at 640 px): each channel's histogram piles up at 233-239 of 255 and falls five
times from 239 to 240, where an overexposed wall close to the scope and the highlights sit,
most of it not within one code of grey (JPEG's chroma noise). Read as light, those values
(3% of each channel's) held half of Lambert's squared error there (`ctjax fit`: RMSE 29.5
levels with them, 20.9 without; docs/real-video.md). So each channel's own histogram is
searched, from the top down, for a *pile-up*: a code holding at least `PILE_SHARE` of the
samples (over `PILE_SMOOTH` codes) whose next codes up hold at most `PILE_DROP` of it and
the codes a few dozen below it at most 1 / `PILE_RISE` of it. Where two channels or more
pile up within `PILE_AGREE` codes of each other, that is the camera's white: every channel
reads as clipped from the pile-up's lower edge (the lowest code down to which the smoothed
histogram stays at half the peak or more, at most `PILE_WIDTH` codes below the peak), or
from its own hinge where that is lower. One channel alone piling up (the sinus's red at
225, beside its hinge at 203) is not a white.

A channel whose second line still rises, by more than `PLATEAU_SLOPE` but at most half as
fast as its first (`SOFT_KNEE_RATIO`), was compressed, not clipped: a camera's knee. Its
values stay light; `knee_note` names it and the effect that models it
(`ctjax.effects.Knee`).
"""

from typing import NamedTuple

import numpy as np

from ._camera_json import AUTO_CEILINGS
from ._encoding import SRGB, srgb_to_linear

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


# A knee (not a ceiling): above the knot the channel still rises, by more than
# `PLATEAU_SLOPE`, but at most 1 / this of its slope below (where the knot is bright, as a
# ceiling's): the camera compressed it there (`ctjax.effects.Knee` models it).
SOFT_KNEE_RATIO = 2.0


# The camera's white: a channel's pile-up holds at least this share of the samples...
PILE_SHARE = 1e-3
# ...in the mean over this many codes (of 255) about its peak...
PILE_SMOOTH = 5
# ...the 3rd to 8th codes above it at most this share of it (a sharp top)...
PILE_DROP = 0.35
# ...and it at least this many times the 24th to 40th codes below it (a pile, not a slope);
PILE_RISE = 2.0
# two channels' peaks within this many codes are one white; its lower edge at most this
# many codes below its peak (the noise and the resampling about the camera's white).
PILE_AGREE = 3
PILE_WIDTH = 12


def ceiling_levels(
    samples, encoding, declared=AUTO_CEILINGS
) -> tuple[tuple[float, ...], list[int | None], int]:
    """Per channel, the decoded level from which its values read as clipped (half a code
    below its ceiling's code, so that every decoding of that code is at or above it; 1.0
    where it has none), the ceilings' codes and full scale. The ceilings are camera.json's
    `declared` ones (`read_ceilings`: "none", or codes) or found on the `samples`
    (`ctjax.io._channel_ceiling`); none found where the images mix bit depths."""
    if len({part.dtype for part in samples}) != 1:
        return (1.0,) * 3, [None] * 3, 0
    top = int(np.iinfo(samples[0].dtype).max)
    if declared == AUTO_CEILINGS:
        ceilings = channel_ceilings(np.concatenate(samples), top)
    else:
        ceilings = [None] * 3 if isinstance(declared, str) else list(declared)
        ceilings = [None if code is None or code >= top else code for code in ceilings]
    levels = tuple(
        1.0 if code is None else float(decoded_level((code - 0.5) / top, encoding))
        for code in ceilings
    )
    return levels, ceilings, top


def decoded_level(recorded: float, encoding: str) -> float:
    return float(srgb_to_linear(np.float64(recorded))) if encoding == SRGB else recorded


def saturation_of(frames, samples, encoding, declared, source) -> tuple[tuple, tuple, str | None]:
    """`Capture.saturation` of the frames, `Capture.ceilings` and a note naming them (None
    without); `source`: where `declared` ceilings come from."""
    levels, ceilings, top = ceiling_levels(samples, encoding, declared)
    if all(code is None for code in ceilings):
        return levels, (None, None, None), None
    values = len(frames) * frames[0].image[..., 0].size
    described = []
    for c, code in enumerate(ceilings):
        if code is not None:
            read = sum(int(np.count_nonzero(f.image[..., c] >= levels[c])) for f in frames)
            described.append(f"{'RGB'[c]} from {code} of {top} ({read / values:.1%} of its values)")
    found = "found on the frames" if declared == AUTO_CEILINGS else source
    return (
        levels,
        tuple(ceilings),
        (
            "a channel of the frames stops below full scale (the camera's ceiling, where it stops "
            f"following the others or the camera's white, {found}): read as clipped there, "
            f'{"; ".join(described)}; camera.json\'s "ceilings": "none" reads every channel to '
            "full scale"
        ),
    )


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
    the light up to the brightest samples (the module doc): where it stops following the
    others, or the camera's white (`white_level`), whichever is lower. `samples`: (N, 3)
    codes."""
    hinges = [_ceiling(*channel_profile(samples, top, c), top) for c in range(samples.shape[-1])]
    white = white_level(samples, top)
    if white is None:
        return hinges
    return [white if code is None else min(code, white) for code in hinges]


def white_level(samples: np.ndarray, top: int) -> int | None:
    """The code value from which every channel reads as clipped where two channels or more
    pile up at one code below full scale (the camera's white, the module doc), or None.
    `samples`: (N, 3) codes."""
    step = top / 255  # 16-bit codes on the 8-bit scale of the constants
    piles = [_pile_up(np.round(samples[:, c] / step)) for c in range(samples.shape[-1])]
    piles = sorted(pile for pile in piles if pile is not None)
    agreeing = [
        edge
        for k, (peak, edge) in enumerate(piles)
        if any(abs(peak - other) <= PILE_AGREE for j, (other, _) in enumerate(piles) if j != k)
    ]
    return round(min(agreeing) * step) if agreeing else None


def _pile_up(codes: np.ndarray) -> tuple[int, int] | None:
    """The highest pile-up below full scale of one channel's 8-bit `codes` (the module
    doc): its peak's code and its lower edge, or None."""
    counts = np.bincount(codes.astype(np.int64), minlength=256).astype(np.float64)
    smooth = np.convolve(counts, np.ones(PILE_SMOOTH) / PILE_SMOOTH, mode="same")
    lowest = int(BRIGHT * 255)
    for peak in range(int(BELOW_FULL_SCALE * 255) - 1, lowest, -1):
        height = smooth[peak]
        if height < PILE_SHARE * len(codes) or height * PILE_SMOOTH < MIN_SAMPLES:
            continue
        below = counts[peak - 40 : peak - 23].mean()
        if (
            counts[peak + 3 : peak + 9].mean() <= PILE_DROP * height
            and height >= PILE_RISE * below
            and below > 0  # a pile the light leads up to, not a flat image's one colour
        ):
            edge = peak
            while edge > max(lowest, peak - PILE_WIDTH) and smooth[edge - 1] >= 0.5 * height:
                edge -= 1
            return peak, edge
    return None


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


def _bright_bend(centres, medians, weights, top: int) -> tuple[float, float, float] | None:
    """The hinge's (level, slope below, slope above) where its knot is bright (`BRIGHT` up
    to `BELOW_FULL_SCALE` of full scale) with `PLATEAU_SPAN` of the others' mean above it,
    or None: where a ceiling or a knee may be."""
    fitted = hinge(centres, medians, weights)
    if fitted is None:
        return None
    k, level, slope, above = fitted
    if BRIGHT * top <= level < BELOW_FULL_SCALE * top and (
        centres[-1] - centres[k] >= PLATEAU_SPAN * top
    ):
        return level, slope, above
    return None


def _ceiling(centres, medians, weights, top: int) -> int | None:
    """The hinge's level where its second line is a plateau (the module doc), or None."""
    bend = _bright_bend(centres, medians, weights, top)
    if bend is None:
        return None
    level, slope, plateau = bend
    if plateau <= PLATEAU_SLOPE and slope >= KNEE_RATIO * max(plateau, 0.05):
        return int(np.ceil(level))
    return None


class ChannelKnee(NamedTuple):
    """A channel a camera's knee compressed (`channel_knees`): its index (0 red), the level
    of the knot in codes of the other channels' mean, its slopes below and above the knot
    (codes per code of that mean) and the images' full scale."""

    channel: int
    level: float
    below: float
    above: float
    top: int


def channel_knees(samples: list[np.ndarray]) -> tuple[ChannelKnee, ...]:
    """The channels that rise markedly slower above a bright knot than below it, though not
    to a plateau (`SOFT_KNEE_RATIO`; a camera's knee: a second sinus video's red, 1.68
    codes per code of green and blue's mean below 162 of 255 and 0.53 above, where the
    shared sinus's has a ceiling, the cholecystectomy video's bends 1.22 -> 0.87 and a
    synthetic capture's not at all); none where the images mix bit depths. `samples`: each
    frame's (N, 3) codes."""
    if not samples or len({part.dtype for part in samples}) != 1:
        return ()
    codes, top = np.concatenate(samples), int(np.iinfo(samples[0].dtype).max)
    found = []
    for channel in range(codes.shape[-1]):
        bend = _bright_bend(*channel_profile(codes, top, channel), top)
        if bend is not None and PLATEAU_SLOPE < bend[2] <= bend[1] / SOFT_KNEE_RATIO:
            found.append(ChannelKnee(channel, *bend, top))
    return tuple(found)


def knee_note(knees: tuple[ChannelKnee, ...]) -> str | None:
    """A note naming the channels a knee compressed (`channel_knees`), or None."""
    if not knees:
        return None
    found = [
        f"{'RGB'[k.channel]} rises {k.above:.2f} codes per code of the other channels' mean "
        f"above {k.level:.0f} of {k.top}, {k.below:.2f} below"
        for k in knees
    ]
    return (
        f"{'; '.join(found)}: the camera compressed it there (a knee; not clipped, it still "
        "rises): evaluate and calibrate-light fit a knee there with the model by default "
        "(`--effects knee` in every channel, `--effects none` none)"
    )
