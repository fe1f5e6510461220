"""Whether the frames agree with one another under a model: each frame's RMSE and its
brightness against what the other frames predict (`HeldOutTracks.frame_rmse` and
`frame_brightness`), the frames the others do not predict and the frames off in brightness:
what `ctjax evaluate` prints beside its RMSEs (`frames_rmse` in its JSON)."""

import math
from collections.abc import Callable, Sequence

import numpy as np

from ._determined import Undetermined, add_undetermined
from ._result import finite_or_none
from ._status import Status

# A calibration frame whose views its neighbours predict this many times worse than the
# calibration frames' median is one the others do not predict (`frames_not_predicted`):
# on the shared sinus's 35 frames the first third reads 21-34 levels against a median of
# 14.4 (frames 0, 1, 7, 9, 10 and 11 above 1.5x), its held-out frames 3.4-9.0; the
# cholecystectomy's 12 frames 16.2-23.3 against 17.8 (none): `benchmarks/frame_consistency.py`.
NOT_PREDICTED_FACTOR = 1.5
# A frame whose brightness its neighbours' views predict off by more than this (natural
# log: 10%) under the fullest model is named by `frame_consistency` (`brightness_off`).
# Under the near light's model (`benchmarks/frame_consistency.py --near`) the frames' log
# brightness spreads by 0.024-0.084 (sd) on five real stretches of 12-24 frames (none to
# five frames named); a synthetic auto-exposure of sd 0.15 in log reads 0.128 (three of six
# frames named), the same capture without it 0.0003.
BRIGHTNESS_OFF_LOG = 0.1


def frame_gains(model, samples, judged=None) -> dict[int, float]:
    """Each frame's measured over predicted brightness under `model`, by frame index: the
    gain g minimising sum w |measured - g predicted|^2 over the frame's `judged` views of
    `samples` (a `TrackSamples`; all observed by default), each view predicted from its
    point's albedo in its other views (`heldout_map_residuals`); NaN for a frame none of
    whose views is predicted."""
    from .fitting._map_least_squares import heldout_map_residuals

    residual, weight = heldout_map_residuals(model, samples, judged)
    measured = 255 * np.asarray(samples.values, float)
    predicted = measured - residual
    frame = np.asarray(samples.site.frame)
    across = np.sum(measured * predicted, axis=0) * weight
    power = np.sum(predicted * predicted, axis=0) * weight
    out = {}
    for f in sorted({int(f) for f in np.unique(frame) if f >= 0}):
        here = (frame == f) & (weight > 0)
        total = float(np.sum(power[here]))
        out[f] = float(np.sum(across[here])) / total if total > 0 else math.nan
    return out


# Undoing the frames' brightness moving a roughness or a lobe's F_tilde (its channels' sum)
# by more than this (relative) flags the lobe (`judge_frames_brightness`).
BRIGHTNESS_MOVES_LOBE = 0.1


def lobe_moved(before: dict[str, np.ndarray], after: dict[str, np.ndarray]) -> float:
    """The largest relative change from `before` to `after` of a lobe's values by name (a
    roughness; a weight's channels' sum, an F_tilde's against at least 0.01 per channel:
    a lobe under that is none, and its changes are not the lobe moving; on the real
    cholecystectomy the near light's F_tilde [0, 0.0067, 0.0047], `no_lobe`, read 23% more
    with frame 0's brightness undone against 0.0114)."""
    return max(
        abs(float(np.sum(after[k])) - float(np.sum(before[k])))
        / max(
            abs(float(np.sum(before[k]))),
            0.01 * np.size(before[k]) if k.startswith("F") else 1e-12,
        )
        for k in before
    )


def _lobe_text(lobe: dict[str, np.ndarray]) -> str:
    return ", ".join(f"{k} {np.round(np.asarray(v, float), 3).tolist()}" for k, v in lobe.items())


def judge_frames_brightness(
    result,
    brightness: dict[int, float],
    names: Sequence[str],
    lobe: dict[str, np.ndarray],
    refit: "Callable[[np.ndarray], tuple[dict, dict] | None] | None",
    *,
    remedy: str,
    parameter: str = "sigma",
    under: str = "this fit",
) -> None:
    """Whether a lobe absorbed a change of brightness between frames: `brightness` (each
    frame's measured over predicted, by frame index) in `result.details` by frame name
    (`frames_brightness`) with the frames off by more than `BRIGHTNESS_OFF_LOG`
    (`brightness_off`). Where frames are off, `refit(gain)` (a gain per frame, 1 for a frame
    not measured) fits again with each frame's brightness undone and returns the lobe's
    values by name and what to record (`brightness_undone`), or None (not refitted: the
    model fits the gains itself, or the refit failed). A lobe (`lobe`: its values here)
    that moves by more than `BRIGHTNESS_MOVES_LOBE` is no measurement: `parameter` gets
    `Status.brightness_off`, with `remedy` in its reason; else a warning only. The paper's
    model and the near light's lack a scope's auto-exposure (`ctjax fit`, `ctjax
    calibrate-light`)."""
    off = {
        names[f]: g
        for f, g in brightness.items()
        if g > 0 and abs(math.log(g)) > BRIGHTNESS_OFF_LOG
    }
    result.details["frames_brightness"] = {
        names[f]: finite_or_none(g) for f, g in brightness.items()
    }
    result.details["brightness_off"] = sorted(off)
    if not off or refit is None:
        return
    gain = np.ones(len(names))
    for f, g in brightness.items():
        gain[f] = g if g > 0 and math.isfinite(g) else 1.0
    undone = refit(gain)
    if undone is None:
        return
    after, record = undone
    result.details["brightness_undone"] = record
    listed = ", ".join(f"{n} {g:.2f}x" for n, g in sorted(off.items())[:6])
    found = (
        f"{len(off)} of {len(brightness)} frames {'is' if len(off) == 1 else 'are'} brighter "
        "or darker than the other frames "
        f"predict under {under} by more than a factor of {math.exp(BRIGHTNESS_OFF_LOG):.2f} "
        f"({listed}{', ...' if len(off) > 6 else ''}); with each frame's brightness undone "
        f"the lobe is {_lobe_text(after)} (here {_lobe_text(lobe)})"
    )
    if lobe_moved(lobe, after) <= BRIGHTNESS_MOVES_LOBE:
        result.warnings.append(
            f"{found}: the lobe does not absorb it, the fit's error does ({remedy})"
        )
        return
    reason = (
        f"{found}: an exposure change between frames (a scope's auto-exposure) or a falloff "
        f"with distance that the model lacks, which the lobe absorbs; {remedy}"
    )
    add_undetermined(result, Undetermined(parameter, Status.brightness_off, reason))


def frames_not_predicted(
    frame_rmse: dict[int, float], calibration: Sequence[int], factor: float = NOT_PREDICTED_FACTOR
) -> tuple[list[int], float]:
    """The calibration frames whose RMSE (`HeldOutTracks.frame_rmse`) exceeds `factor`
    times the calibration frames' median, and that median. A frame the others do not
    predict raises their figures too (their views' albedos take its values in): on a
    128x96 x 5 synthetic capture with one frame's image shifted by 3 px, that frame read
    16.7 levels against a median of 8.2 over 4 calibration frames (2.0-2.3 unshifted), and
    1.54x the median over 3: with few frames, a bad one may go unnamed."""
    values = [frame_rmse[f] for f in calibration if math.isfinite(frame_rmse.get(f, math.nan))]
    if not values:
        return [], math.nan
    median = float(np.median(values))
    return [f for f in calibration if frame_rmse.get(f, math.nan) > factor * median], median


def frame_consistency(tracks, models: dict) -> dict:
    """Each frame's RMSE (8-bit levels) under each of `models` (by name;
    `HeldOutTracks.frame_rmse`), by frame name, the calibration frames the others do not
    predict under the first model (`frames_not_predicted`), the frames with no judged view
    (`not_judged`: none of their pixels on a surface point another frame sees, a frame whose
    depth, normals or pose disagree with the others'), and each frame's brightness against
    what the others predict under the last model (`HeldOutTracks.frame_brightness`, the
    fullest: its light's falloff accounts for the distance) with the frames off by more
    than `BRIGHTNESS_OFF_LOG` (`brightness_off`), as JSON. `tracks`: a `HeldOutTracks`."""
    names = [frame.name for frame in tracks.capture.frames]
    rmse = {name: tracks.frame_rmse(model) for name, model in models.items()}
    first = next(iter(rmse.values()))
    outliers, median = frames_not_predicted(first, tracks.calibration)
    last, fullest = list(models.items())[-1]
    brightness = tracks.frame_brightness(fullest)
    off = [
        names[f]
        for f, g in sorted(brightness.items())
        if g > 0 and abs(math.log(g)) > BRIGHTNESS_OFF_LOG
    ]

    return {
        **{
            name: {names[f]: finite_or_none(v) for f, v in sorted(r.items())}
            for name, r in rmse.items()
        },
        "calibration_median_levels": finite_or_none(median),
        "not_predicted": [names[f] for f in outliers],
        "not_judged": [names[f] for f, v in sorted(first.items()) if not math.isfinite(v)],
        "brightness": {names[f]: finite_or_none(g) for f, g in sorted(brightness.items())},
        "brightness_model": last,
        "brightness_off": off,
        "note": (
            "8-bit levels per frame: a calibration frame's views each predicted from the "
            "point's albedo in its other views, a test frame's judged views as the test RMSE "
            f"counts them; not_predicted: calibration frames above {NOT_PREDICTED_FACTOR}x "
            f"the calibration frames' median under the {next(iter(rmse))} model (tissue or "
            "scope motion the poses and shape do not follow, blur): no lobe explains them, "
            "and they weigh on the fit; `ctjax fit` on a capture without them says what "
            "they change; not_judged: frames none of whose views was judged (their "
            "depth, normals or pose put none of their pixels on a point the others see); "
            "brightness: each frame's measured over predicted values (the gain that fits "
            "them best) under the brightness_model, each view predicted from the point's "
            "albedo in its other views: 1 where the model accounts for the frame's "
            f"brightness; brightness_off: frames off by more than {BRIGHTNESS_OFF_LOG:g} in "
            "natural log, an exposure change the model lacks (a scope's auto-exposure: "
            "--effects frame_exposure) or motion it does not follow"
        ),
    }
