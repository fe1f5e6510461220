"""A scope's auto-exposure in the branch and bound: a gain per frame on the tracks' views.

The paper's model with an albedo map, each view of frame f times g_f (the first frame's
1: the albedos carry the scale). For fixed gains the fit is the branch and bound on the
views with the gains undone (values over g_f, weights times g_f^2: the noise scaled
alike), so the gains are fitted by alternation: the BRDF given the gains, then each
frame's gain from its brightness against what the other frames predict under that BRDF
(`frame_brightness`: each view predicted from its point's albedo in the other frames),
until no frame's brightness moves by more than `EXPOSURE_TOLERANCE` (in log).

On `ctjax synth --exposure 0.1` (128x96 x 5) the first step alone took F_tilde from
0.19-0.25 to 0.31-0.32 (truth 0.3); five fits in all brought the exposures within 0.001 of
the truth (log), sigma to 0.19996 and F_tilde to 0.298-0.299. On SCARED 61-84 (24 frames of
a da Vinci, 640 px) 11 fits, the gains 0.82-1.05.
"""

import math

import equinox as eqx
import numpy as np

from .._convert import on_device
from .._errors import CtjaxError
from ._branch_and_bound_map import (
    AlbedoMapFit,
    TrackShading,
    fit_brdf_map,
    frame_brightness,
    rgb_rmse_recorded,
)
from ._brdf import BRDFFamily

# The alternation stops when every frame's brightness under the last fit is within this
# (natural log) of what the other frames predict...
EXPOSURE_TOLERANCE = 2e-3
# ...or after this many fits.
EXPOSURE_ROUNDS = 12


def view_gains(frame: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Each view's gain (M, P): `gain[f]` for a view of frame f, 1 where `frame` is -1."""
    return np.where(frame >= 0, gain[np.maximum(frame, 0)], 1.0)


def undo_gains(shading: TrackShading, frame: np.ndarray, gain: np.ndarray) -> TrackShading:
    """`shading` with every view of frame f over `gain[f]` and its weight times
    `gain[f]`^2; `frame` (M, P) as `shading.weight`, -1 for a view no gain applies to."""
    per_view = view_gains(frame, gain)
    dtype = shading.weight.dtype
    values = on_device(np.asarray(shading.values) / per_view[None], dtype)
    weight = on_device(np.asarray(shading.weight) * per_view**2, dtype)
    return eqx.tree_at(lambda s: (s.values, s.weight), shading, (values, weight))


def fit_frame_exposure(
    shading: TrackShading,
    frame: np.ndarray,
    frames: int,
    family: BRDFFamily,
    tolerance: float,
    instant: np.ndarray | None = None,
) -> tuple[AlbedoMapFit, TrackShading, np.ndarray, int]:
    """The BRDF with an albedo map and a gain per frame (see the module doc). `frame`: the
    frame of each view (M, P; -1: not counted in a frame's brightness), `frames` their
    number; `instant`: the frame whose gain each view takes (default `frame`; a stereo
    capture's right views take their instant's, as one exposure for both cameras).
    Returns the fit, the shading with the gains undone, the gains' logs over the first
    frame's (frames - 1,) and the number of fits."""
    instant = frame if instant is None else instant
    gain, rounds = np.ones(frames), 0
    while rounds < EXPOSURE_ROUNDS:
        rounds += 1
        undone = undo_gains(shading, instant, gain)
        fit = fit_brdf_map(undone, family, tolerance=tolerance)
        brightness = frame_brightness(fit, undone, frame)
        step = np.ones(frames)
        for f, g in brightness.items():
            if g > 0 and math.isfinite(g):
                step[f] = g
        if not (step[0] > 0 and math.isfinite(brightness.get(0, math.nan))):
            raise CtjaxError(
                "the frames' exposure is relative to the first frame's, whose views no other "
                "frame predicts (no surface point seen in it and in another frame)"
            )
        if np.max(np.abs(np.log(step / step[0]))) <= EXPOSURE_TOLERANCE:
            break
        gain = gain * step / step[0]
    return in_recorded_levels(fit, undone, instant, gain), undone, np.log(gain[1:]), rounds


def in_recorded_levels(
    fit: AlbedoMapFit, undone: TrackShading, frame: np.ndarray, gain: np.ndarray
) -> AlbedoMapFit:
    """`fit` (of `undone`: the views over their frames' `gain`) with its RMSE in the
    recorded values' levels (`rgb_rmse_recorded`), as without the gains."""
    rmse = rgb_rmse_recorded(fit, undone, view_gains(frame, gain))
    return eqx.tree_at(lambda f: f.rgb_rmse, fit, np.asarray(rmse, np.asarray(fit.rgb_rmse).dtype))
