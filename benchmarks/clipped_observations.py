"""What the clipped observations would tell the BRDF fit: dropped (ctjax today), more of
the near-white ones dropped, or kept as censored observations (the model at least the
clip level there).

    .venv/bin/python benchmarks/clipped_observations.py [CAPTURE ...]

Without captures: a synthetic one generated here (`ctjax synth`, 160x128 x 6 frames,
sigma 0.2, F_tilde 0.3, textured; its specular cores clip). For each capture, the paper's
BRDF with the albedo map on the tracks `fit` uses (one normal per point), three ways:

- `dropped`: as `fit` does, every observation with a clipped channel (1.0 in the linear
  image at any of its four bilinear corners) left out;
- `dropped_0.9`: every observation with a channel at 0.9 or more left out too (the tracks'
  `saturation_level`);
- `censored`: the clipped observations kept as lower bounds, by active set: fit without
  them, then add those whose clipped channels the model puts below their measured value
  (the bilinear sample there is a lower bound of the true one), fit again, until that set
  stops changing. Only at points whose albedo two or more unclipped views pin: elsewhere
  the albedo alone meets any bound.

Prints per capture and way: sigma, F_tilde, the RMSE of the fitted observations and, for
`censored`, how many clipped observations there are, how many are active at the end and
how far below its bound the first fit puts the model (median and 90th percentile, levels).
Measured at b19bb63 (12 frames at 640 px; docs/real-video.md, "The brightest
observations"): censoring moved nothing on the synthetic capture (sigma 0.2004 -> 0.2002,
F_tilde 0.296 -> 0.298) nor on the real ones (cholecystectomy sigma 0.390 -> 0.386,
SurgT F_tilde ~1e-4 both ways).
"""

import argparse
import tempfile
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _results import emit

import ctjax._tracks as tracks_module
from ctjax._buckets import bucket
from ctjax.estimation import PAPER
from ctjax.estimation._branch_and_bound_map import (
    _per_point_index,
    fit_brdf_map,
    track_columns,
    track_shading,
)
from ctjax.io import load_capture
from ctjax.observations import Observations
from ctjax.synth import SynthOptions, synthesize

ACTIVE_SET_ROUNDS = 6


def _tracks(root: Path, saturation_level: float):
    defaults = tracks_module.follow.__kwdefaults__
    kept = defaults["saturation_level"]
    defaults["saturation_level"] = saturation_level
    try:
        return Observations.of(load_capture(root)).tracks(), load_capture(root)
    finally:
        defaults["saturation_level"] = kept


def _clipped(tracks, capture) -> np.ndarray:
    """(P, M, 3): a corner of nonzero weight clipped (1.0) in that channel."""
    out = np.zeros((*tracks.observed.shape, 3), bool)
    for f, frame in enumerate(capture.frames):
        image = np.asarray(frame.image)
        at = (tracks.frame == f) & tracks.observed
        pixel = np.rint(tracks.corner_pixel[at]).astype(int)  # (K, 4, 2): (u, v)
        cols = np.clip(pixel[..., 0], 0, image.shape[1] - 1)
        rows = np.clip(pixel[..., 1], 0, image.shape[0] - 1)
        corner = (image[rows, cols] >= 1.0) & (tracks.corner_weight[at] > 0)[..., None]
        out[at] = corner.any(1)
    return out


def _model(shading, fit, per_point):
    weights = np.asarray(fit.weights)
    columns = track_columns(PAPER, fit.params, shading)
    return sum(
        c * (fit.albedo.T[:, None, :] if k == per_point else weights[k][:, None, None])
        for k, c in enumerate(columns)
    )


def _row(name, way, fit, per_point, **extra):
    lobes = [k for k in range(len(fit.weights)) if k != per_point]
    return {
        "capture": name,
        "way": way,
        "sigma": round(float(fit.params[0]), 4),
        "F_tilde": np.round(np.asarray(fit.weights)[lobes][0], 4).tolist(),
        "rgb_rmse": round(float(fit.rgb_rmse), 3),
        **extra,
    }


def run(root: Path, name: str) -> None:
    per_point = _per_point_index(PAPER)
    for way, level in (("dropped", 1.0), ("dropped_0.9", 0.9)):
        tracks, _ = _tracks(root, level)
        shading = track_shading(tracks.padded(bucket(len(tracks))))
        emit(_row(name, way, fit_brdf_map(shading, PAPER), per_point))

    tracks, capture = _tracks(root, 2.0)  # nothing clipped: every observation kept
    size = bucket(len(tracks))
    shading = track_shading(tracks.padded(size))
    clipped = np.zeros((size, *tracks.observed.shape[1:], 3), bool)
    clipped[: len(tracks)] = _clipped(tracks, capture)
    clipped = jnp.asarray(np.transpose(clipped, (2, 1, 0)))  # (3, M, P): views first
    start = shading.weight
    any_clipped = clipped.any(0) & (start > 0)
    pinned = jnp.sum((start > 0) & ~any_clipped, axis=0) >= 2
    candidates = any_clipped & pinned[None]
    active = jnp.zeros_like(candidates)
    below_levels = None
    for _ in range(ACTIVE_SET_ROUNDS):
        weighted = eqx.tree_at(
            lambda s: s.weight, shading, jnp.where(any_clipped & ~active, 0.0, start)
        )
        fit = fit_brdf_map(weighted, PAPER)
        model = _model(weighted, fit, per_point)
        if below_levels is None:
            gap = 255 * np.asarray(shading.values - model)[np.asarray(clipped & candidates)]
            below_levels = np.percentile(gap, [50, 90]).round(2).tolist() if gap.size else []
        below = jnp.all(jnp.where(clipped, model < shading.values, True), axis=0)
        now = candidates & below
        if bool(jnp.all(now == active)):
            break
        active = now
    extra = {
        "clipped_observations": int(any_clipped.sum()),
        "at_pinned_points": int(candidates.sum()),
        "active": int(active.sum()),
        "first_fit_value_minus_model_levels_p50_p90": below_levels,
    }
    emit(_row(name, "censored", fit, per_point, **extra))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("captures", nargs="*", type=Path)
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    if args.captures:
        for root in args.captures:
            run(root, root.name)
        return
    with tempfile.TemporaryDirectory() as folder:
        options = SynthOptions(width=160, height=128, frames=6)
        run(synthesize(Path(folder) / "synthetic", options), "synthetic")


if __name__ == "__main__":
    main()
