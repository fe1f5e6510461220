"""Whether the near light's lobe absorbed a change of brightness between frames, as `ctjax
fit` checks its own (`ctjax.estimation._map_fit`): each frame's brightness against what
the other frames predict under the model refitted on every frame (`frame_gains`), and where
frames are off by more than `BRIGHTNESS_OFF_LOG`, the model refitted (as on every frame) on
the views with that brightness undone. A lobe that moves by more than
`BRIGHTNESS_MOVES_LOBE` is no measurement (`Status.brightness_off`): a scope's
auto-exposure the model lacks (`--effects frame_exposure` fits it).
"""

import math

import equinox as eqx
import numpy as np

from .._convert import on_device
from .._determined import Undetermined, add_undetermined
from .._frame_consistency import BRIGHTNESS_OFF_LOG, frame_gains
from .._json import named_parameters
from .._status import Status
from ..fitting import TrackSamples

# Undoing the frames' brightness moving sigma or F_tilde (its channels' sum) by more than
# this (relative) flags the lobe, as `fit`'s check does.
BRIGHTNESS_MOVES_LOBE = 0.1


def check_frames_brightness(result, model, tracks, refit, names: list[str]) -> None:
    """`result`'s `frames_brightness` and `brightness_off` under `model` on `tracks` (every
    frame's surface points); where frames are off and `model` has no image effects, the
    model refitted by `refit(samples)` (as on every frame: the light too) on the views with
    each frame's brightness undone (`brightness_undone`), the lobe flagged where it moves."""
    samples = tracks if isinstance(tracks, TrackSamples) else TrackSamples.of(tracks)
    gains = frame_gains(model, samples)
    off = {names[f]: g for f, g in gains.items() if g > 0 and abs(math.log(g)) > BRIGHTNESS_OFF_LOG}
    result.details["frames_brightness"] = {
        names[f]: (g if math.isfinite(g) else None) for f, g in gains.items()
    }
    result.details["brightness_off"] = sorted(off)
    if not off or tuple(getattr(model, "effects", ())):
        return
    gain = np.ones(len(names))
    for f, g in gains.items():
        gain[f] = g if g > 0 and math.isfinite(g) else 1.0
    frame = np.asarray(samples.site.frame)
    per_view = np.where(frame >= 0, gain[np.maximum(frame, 0)], 1.0)
    values = np.asarray(samples.values) / per_view[None]
    weight = np.asarray(samples.weight) * per_view**2
    dtype = samples.weight.dtype
    undone = eqx.tree_at(
        lambda s: (s.values, s.weight),
        samples,
        (on_device(values, dtype), on_device(weight, dtype)),
    )
    again = refit(undone)
    if not np.isfinite(again.cost):
        return
    before, after = _lobe(model), _lobe(again.model)
    result.details["brightness_undone"] = {k: v.tolist() for k, v in after.items()}
    moved = max(
        abs(float(np.sum(after[k])) - float(np.sum(before[k])))
        / max(abs(float(np.sum(before[k]))), 0.01 if k.startswith("F") else 1e-12)
        for k in before
    )
    listed = ", ".join(f"{n} {g:.2f}x" for n, g in sorted(off.items())[:6])
    found = (
        f"{len(off)} of {len(gains)} frames are brighter or darker than the other frames "
        f"predict under this model by more than a factor of {math.exp(BRIGHTNESS_OFF_LOG):.2f}"
        f" ({listed}{', ...' if len(off) > 6 else ''}); with each frame's brightness undone "
        f"the lobe is {_text(after)} (here {_text(before)})"
    )
    if moved <= BRIGHTNESS_MOVES_LOBE:
        result.warnings.append(f"{found}: the lobe does not absorb it")
        return
    reason = (
        f"{found}: an exposure change between frames (a scope's auto-exposure) that the "
        "model lacks, which the lobe absorbs; `--effects frame_exposure` fits a gain per frame"
    )
    add_undetermined(result, Undetermined("sigma", Status.brightness_off, reason))


def _lobe(model) -> dict[str, np.ndarray]:
    """The model's roughnesses and lobe weights by paper name (`sigma`, `F_tilde`...)."""
    named = named_parameters(model)
    return {
        k: np.asarray(v, float)
        for k, v in named.items()
        if k.startswith("sigma") or k.startswith("F_tilde")
    }


def _text(lobe: dict) -> str:
    return ", ".join(f"{k} {np.round(v, 3).tolist()}" for k, v in lobe.items())
