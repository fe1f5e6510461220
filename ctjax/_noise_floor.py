"""The noise floor: how far from a model any model could come, in 8-bit levels, read from
the residual images' second differences (a smooth model error cancels in them, pixel noise
does not). The held-out protocol (`ctjax.heldout`) judges every model against it."""

import math
from collections.abc import Sequence

import numpy as np

from ._errors import CtjaxError
from .io import Capture
from .observations import Observations


def noise_floor_levels(capture: Capture, frames: Sequence[int], model) -> float:
    """Pixel noise (8-bit levels) from second differences of residuals along rows and columns.

    `r[i-1] - 2 r[i] + r[i+1]` cancels any residual that varies linearly over three pixels
    (a smooth model error, even a large one), and has variance 6 sigma^2 for independent
    noise. Outliers (highlights' edges) are clipped iteratively at 4 standard deviations;
    not the median absolute deviation, which is biased here because the second difference
    of a smooth image quantised to 8 bits takes nearly integer values.
    """
    obs = Observations.of(capture)
    residuals = []
    for index in frames:
        frame = obs.frames[index]
        rendered = np.asarray(model.render(obs.camera, frame.normals, frame.depth, index))
        residuals.append((rendered - frame.image, obs.usable[index]))
    return second_differences_floor(residuals)


def noise_floor_map_levels(capture, frames: Sequence[int], model) -> float:
    """The noise floor (8-bit levels) on textured tissue: `noise_floor_levels` on residual
    images under the albedo map (each pixel against the albedo the other frames that see it
    give, `ctjax.estimation._dense_maps.map_residuals`), so that the texture is not counted
    as noise."""
    from .estimation._dense_maps import map_residuals
    from .fitting._map_least_squares import diffuse_lobe

    obs = Observations.of(capture)
    images = map_residuals(
        obs.capture,
        model.brdf,
        model.light,
        frames,
        per_point=diffuse_lobe(model),
        effects=tuple(model.effects),
    )
    return second_differences_floor([(r, np.all(np.isfinite(r), axis=-1)) for r in images])


def second_differences_floor(residuals) -> float:
    """The noise (8-bit levels) of residual images [(H, W, 3), usable (H, W)] (linear
    units) from their second differences (see `noise_floor_levels`)."""
    differences = []
    for residual, usable in residuals:
        residual = np.where(usable[..., None], residual, 0.0) * 255
        for r, u in ((residual, usable), (np.swapaxes(residual, 0, 1), usable.T)):
            second = r[:-2] - 2 * r[1:-1] + r[2:]
            both = u[:-2] & u[1:-1] & u[2:]
            differences.append(second[both].reshape(-1))
    d = np.concatenate(differences)
    if d.size < 100:
        raise CtjaxError("too few usable neighbouring pixels to estimate the noise floor")
    kept = d
    for _ in range(5):
        spread = np.std(kept)
        kept = d[np.abs(d - np.mean(kept)) < 4 * spread]
    # A Gaussian clipped at 4 sigma keeps 99.9% of its variance.
    return float(np.std(kept) / math.sqrt(6))
