"""The lobe of a calibrated light's BRDF on the even and on the odd frames apart.

`ctjax fit` checks its lobe's roughness across frame subsets (a lobe the data determine
comes out of both alike; on real video the even and odd frames of one segment gave sigma
0.28 and 0.82 while each fit's standard error was small). `calibrate-light` fits the BRDF
with the light: here the chosen model's BRDF is refitted on the views of the even and of the
odd frames alone, the light and the image effects held where the fit put them, and each
roughness's two values go to `ctjax._determined.halves_apart`: on tracks with the albedo
map (`lobe_halves`), on pixel samples with one albedo (`pixel_lobe_halves`), on either as
the light field's fit takes them (`sample_lobe_halves`).
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._determined import ROUGHNESS
from .._json import named_parameters
from ..fitting._map_least_squares import TrackSamples
from ..fitting._parameters import free_parameters

# Two frames per half at least, as `fit`'s and the offset's halves.
MIN_FRAMES_FOR_HALVES = 4


def lobe_halves(model, tracks, fit) -> dict[str, tuple[float, float]]:
    """`model`'s roughnesses (by paper name: `sigma`, `sigma_2`, ...) refitted on the views
    of `tracks`' even and odd frames alone (the other half's views weighted 0), every
    parameter but the BRDF's held: {name: (even, odd)}. `fit(starts, tracks, freeze=...)`
    is the calibration's fitter. {} with fewer than `MIN_FRAMES_FOR_HALVES` frames, a
    model without a roughness, or a half whose refit is not finite."""
    seen = tracks.observed & (tracks.frame >= 0)

    def half(parity):
        keep = seen & (tracks.frame % 2 == parity)
        return dataclasses.replace(tracks, weight=np.where(keep, tracks.weight, 0.0))

    return _refitted(model, np.unique(tracks.frame[seen]), half, fit)


def pixel_lobe_halves(model, samples, fit) -> dict[str, tuple[float, float]]:
    """`lobe_halves` on pixel `samples` (`ctjax.observations.PixelSamples`, one albedo):
    each half the samples of its frames, as many in both (the larger half's taken evenly
    spaced: the samples are in frame order), so that one compiled fit serves both."""
    frame = np.asarray(samples.frame)
    picks = [np.flatnonzero(frame % 2 == parity) for parity in (0, 1)]
    count = min(len(p) for p in picks)

    def half(parity):
        pick = picks[parity]
        index = pick[np.linspace(0, len(pick) - 1, count).round().astype(int)]
        return jax.tree_util.tree_map(lambda leaf: leaf[index], samples)

    return _refitted(model, np.unique(frame), half, fit) if count else {}


def sample_lobe_halves(model, samples, fit) -> dict[str, tuple[float, float]]:
    """`lobe_halves` on the fitters' samples: `TrackSamples` (the albedo map; the other
    half's observations weighted 0) or pixel samples (`pixel_lobe_halves`)."""
    if not isinstance(samples, TrackSamples):
        return pixel_lobe_halves(model, samples, fit)
    frame = np.asarray(samples.site.frame)
    seen = (frame >= 0) & (np.asarray(samples.weight) > 0)

    def half(parity):
        keep = seen & (frame % 2 == parity)
        weight = jnp.where(jnp.asarray(keep), samples.weight, 0)
        return eqx.tree_at(lambda s: s.weight, samples, weight)

    return _refitted(model, np.unique(frame[seen]), half, fit)


def _refitted(model, frames, half, fit) -> dict[str, tuple[float, float]]:
    """The roughnesses refitted on `half(0)` and on `half(1)`, the rest held."""
    named = named_parameters(model)
    roughnesses = [n for n, v in named.items() if n.startswith(ROUGHNESS) and np.ndim(v) == 0]
    if len(frames) < MIN_FRAMES_FOR_HALVES or not roughnesses:
        return {}
    held = tuple(p.name for p in free_parameters(model) if not p.name.startswith("brdf"))
    parts = []
    for parity in (0, 1):
        refit = fit([model], half(parity), freeze=held)
        if not np.isfinite(refit.cost):
            return {}
        parts.append(named_parameters(refit.model))
    return {n: (float(parts[0][n]), float(parts[1][n])) for n in roughnesses}
