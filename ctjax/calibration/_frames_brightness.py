"""Whether the near light's lobe absorbed a change of brightness between frames, as `ctjax
fit` checks its own (`ctjax.estimation._map_fit`): each frame's brightness against what
the other frames predict under the model refitted on every frame (`frame_gains`), and where
frames are off by more than `BRIGHTNESS_OFF_LOG`, the model refitted (as on every frame) on
the views with that brightness undone. A lobe that moves by more than
`BRIGHTNESS_MOVES_LOBE` (`ctjax._frame_consistency.judge_frames_brightness`) is no
measurement (`Status.brightness_off`): a scope's auto-exposure the model lacks
(`--effects frame_exposure` fits it).
"""

import equinox as eqx
import numpy as np

from .._convert import on_device
from .._frame_consistency import frame_gains, judge_frames_brightness
from .._json import named_parameters
from ..fitting import TrackSamples, frame_gains_of_pixels, pixel_predict


def check_frames_brightness(result, model, tracks, refit, names: list[str]) -> None:
    """`result`'s `frames_brightness` and `brightness_off` under `model` on `tracks` (every
    frame's surface points); where frames are off and `model` has no image effects, the
    model refitted by `refit(samples)` (as on every frame: the light too) on the views with
    each frame's brightness undone (`brightness_undone`), the lobe flagged where it moves
    (`judge_frames_brightness`)."""
    samples = tracks if isinstance(tracks, TrackSamples) else TrackSamples.of(tracks)

    def undone(gain):
        frame = np.asarray(samples.site.frame)
        per_view = np.where(frame >= 0, gain[np.maximum(frame, 0)], 1.0)
        values = np.asarray(samples.values) / per_view[None]
        weight = np.asarray(samples.weight) * per_view**2
        dtype = samples.weight.dtype
        again = refit(
            eqx.tree_at(
                lambda s: (s.values, s.weight),
                samples,
                (on_device(values, dtype), on_device(weight, dtype)),
            )
        )
        if not np.isfinite(again.cost):
            return None
        after = _lobe(again.model)
        return after, {k: v.tolist() for k, v in after.items()}

    judge_frames_brightness(
        result,
        frame_gains(model, samples),
        names,
        _lobe(model),
        None if tuple(getattr(model, "effects", ())) else undone,
        remedy="`--effects frame_exposure` fits a gain per frame",
        under="this model",
    )


def check_pixel_brightness(result, model, samples, refit, names: list[str]) -> None:
    """The same with one albedo (`near_light_uniform`) on pixel `samples` (the calibration
    frames'): each frame's brightness against `model`'s prediction
    (`frame_gains_of_pixels`), and where frames are off and `model` has no image effects,
    `refit(samples)` on the samples with each frame's brightness undone."""

    def undone(gain):
        values = np.asarray(samples.values) / gain[np.asarray(samples.frame)][:, None]
        again = refit(
            eqx.tree_at(lambda s: s.values, samples, on_device(values, samples.values.dtype))
        )
        if not np.isfinite(again.cost):
            return None
        after = _lobe(again.model)
        return after, {k: v.tolist() for k, v in after.items()}

    judge_frames_brightness(
        result,
        frame_gains_of_pixels(model, samples, pixel_predict),
        names,
        _lobe(model),
        None if tuple(getattr(model, "effects", ())) else undone,
        remedy="`--effects frame_exposure` fits a gain per frame",
        under="this model",
    )


def _lobe(model) -> dict[str, np.ndarray]:
    """The model's roughnesses and lobe weights by paper name (`sigma`, `F_tilde`...)."""
    named = named_parameters(model)
    return {
        k: np.asarray(v, float)
        for k, v in named.items()
        if k.startswith("sigma") or k.startswith("F_tilde")
    }
