"""A facet only where the point shone: the lobe about each point's own facet with the
facets allowed only at the views whose point came within r px of S in another view, every
other view predicted by Lambert's model (no lobe), in the calibration frames' choice of
sigma and F_tilde as in the judging of the test frames.

    python benchmarks/facets_where_shone.py CAPTURE [EFFECT ...]

`ctjax evaluate --no-sfs --facets on`'s protocol (the near light fitted on the first 60% of
the frames, with the image effects named, e.g. `frame_exposure`; the facets judged on the
views with those effects undone). For each set of candidate facets (`FACET_CANDIDATES`) and
each rule (facets everywhere, as `evaluate`, or only where another view of the point lies
within 1, 3 or 7 px of S) the grid of sigma and F_tilde is chosen on the calibration views
(each predicted from the point's other calibration views) and the test views judged with
the facets everywhere and only where the point shone. Prints each choice's calibration RMSE
(by which a rule would be chosen) and the test ratios over Lambert's RMSE under the same
light.

Why: on the second sinus video at every 2nd frame the facet lobe takes 44% of the error of
the test views in S at points that shone elsewhere, and loses it on views far from S at
points that never did (docs/real-video.md, "Where the facet lobe's gain lies"). A facet is
read from a sparkle; where a point never sparkled the least squares of its other views
choose one from sheen and noise.

Measured (2026-12-06, 0faad68; 24 frames at 640 px, 60% calibrating; "3 px": the rule at 3 px
in both the choice and the judging):

| capture | facets everywhere | only where shone (3 px) | calibration RMSE: the two |
|---|---|---|---|
| second sinus A at every 2nd frame | 1.000x | 0.908x | 11.33 / 14.27 levels |
| the same, `frame_exposure` | 1.011x | 0.899x (F_tilde 0.011) | 6.98 / 7.37 |
| SCARED 61-84 | 0.722x | 0.760x | 9.88 / 10.34 |

The calibration views prefer the facets everywhere on both: the rule cannot be chosen per
sequence by them, and as a fixed rule it takes the sinus to the bar (0.90x) and gives back
a sixth of SCARED's gain (its sheen below S's threshold). Not made a default.

Slow (the near light, the facets' grid on every rule: 10-20 minutes on 2 cores): a
benchmark, not a test.
"""

import argparse
import math

import jax
import numpy as np
from _results import emit
from sparkle_recurrence import distance_to_s

RADII_PX = (1, 3, 7)


def _shone_elsewhere(distance, weight, radius) -> np.ndarray:
    """(M, P): whether another counted view of the same point lies within `radius` px of
    its frame's S (the judged view's own distance unused: it is what is predicted)."""
    near = (distance < radius) & (weight > 0)
    return (near.sum(axis=0)[None, :] - near) > 0


def _squared(judgement) -> np.ndarray:
    """(M, P) weighted squared residual (levels^2, the channels' mean) of a judgement."""
    return judgement.weight * np.mean(judgement.residual**2, axis=0)


def where_shone(root, effects=()) -> dict:
    from ctjax._performance import enable_compilation_cache
    from ctjax.evaluation import _evaluate
    from ctjax.fitting import FACET_CANDIDATES
    from ctjax.fitting._facet_lobe import FACET_F_TILDES, FACET_SIGMAS, chosen_on_grid
    from ctjax.fitting._facets import (
        FACET_PENALTY,
        FACET_REFINE_STEPS,
        _judgements,
        facet_heldout,
        facet_model,
    )
    from ctjax.io import load_capture

    enable_compilation_cache()
    kept = {}
    facet_lobe = _evaluate._facet_lobe

    def keeping(tracks, model, *args):  # evaluate's held-out tracks and fitted model
        kept["tracks"], kept["model"] = tracks, model
        return facet_lobe(tracks, model, *args)

    _evaluate._facet_lobe = keeping
    try:
        evaluation = _evaluate.evaluate(
            load_capture(root), sfs=False, facets=True, effects=tuple(effects)
        )
    finally:
        _evaluate._facet_lobe = facet_lobe
    observations = kept["tracks"].capture
    tracks, model = kept["tracks"].in_radiance(kept["model"])
    light = model.light
    frames = observations.capture.frames
    rotations = np.stack([np.asarray(f.pose, float)[:3, :3] for f in frames])
    train, test, judged = tracks.train, tracks.test, tracks.judged

    def lambert(samples, which):
        return facet_heldout(facet_model(light, 0.1, 0.0), samples, which, rotations, across=(0.0,))

    train_weight = np.asarray(train.weight)
    train_distance = distance_to_s(observations, train)
    train_lambert = lambert(train, train_weight > 0)
    train_plain = _squared(train_lambert)
    total = float(np.sum(train_lambert.weight))
    rules = (None, *RADII_PX)
    gates = {r: _shone_elsewhere(train_distance, train_weight, r) for r in RADII_PX}
    grids = {(name, r): {} for name in FACET_CANDIDATES for r in rules}
    for name, across in FACET_CANDIDATES.items():
        for sigma in FACET_SIGMAS:
            judgements = _judgements(
                facet_model(light, sigma, FACET_F_TILDES[0]), train, train_weight > 0,
                rotations, FACET_F_TILDES, FACET_PENALTY, "lobe", None, 0, across,
            )  # fmt: skip
            for f_tilde, judgement in zip(FACET_F_TILDES, judgements, strict=True):
                squared = _squared(judgement)
                for r in rules:
                    ssr = squared if r is None else np.where(gates[r], squared, train_plain)
                    grids[(name, r)][(sigma, f_tilde)] = math.sqrt(ssr.sum() / total)
    test_distance = distance_to_s(observations, test)
    test_weight = np.asarray(test.weight)
    test_plain = lambert(test, judged)
    plain = _squared(test_plain)
    out = {
        "capture": str(root),
        "effects": list(effects),
        "evaluate_facets": {k: evaluation.facets[k] for k in ("sigma", "F_tilde", "ratio")},
        "lambert_same_light_rmse": test_plain.rmse,
        "calibration_lambert_rmse": math.sqrt(train_plain.sum() / total),
        "choices": [],
    }
    for (name, r), grid in grids.items():
        sigma, f_tilde = chosen_on_grid(grid)
        lobe = facet_heldout(
            facet_model(light, sigma, f_tilde), test, judged, rotations,
            refine_steps=FACET_REFINE_STEPS, across=FACET_CANDIDATES[name],
        )  # fmt: skip
        squared = _squared(lobe)
        judged_where = {
            radius: math.sqrt(
                np.where(_shone_elsewhere(test_distance, test_weight, radius), squared, plain).sum()
                / plain.sum()
            )
            for radius in RADII_PX
        }
        out["choices"].append(
            {
                "candidates": name,
                "chosen_where_shone_px": r,
                "sigma": sigma,
                "F_tilde": f_tilde,
                "calibration_rmse": min(grid.values()),
                "ratio_everywhere": lobe.rmse / test_plain.rmse,
                "ratio_where_shone": judged_where,
            }
        )
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", help="a reconstructed capture (depth, normals, poses)")
    parser.add_argument("effects", nargs="*", help="image effects fitted with the models")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    found = where_shone(args.capture, args.effects)
    facets = found["evaluate_facets"]
    print(
        f"{found['capture']} (effects: {', '.join(found['effects']) or 'none'}): evaluate's "
        f"facet lobe sigma {facets['sigma']:.3f}, F_tilde {facets['F_tilde']:.4f}, "
        f"{facets['ratio']:.3f}x; Lambert under the same light "
        f"{found['lambert_same_light_rmse']:.2f} levels (calibration "
        f"{found['calibration_lambert_rmse']:.2f})"
    )
    for row in found["choices"]:
        rule = row["chosen_where_shone_px"]
        rule = "everywhere" if rule is None else f"where shone ({rule} px)"
        print(
            f"  {row['candidates']:>15}, chosen {rule:>21}: calibration "
            f"{row['calibration_rmse']:.2f} levels, sigma {row['sigma']:.3f}, F_tilde "
            f"{row['F_tilde']:.4f}; test "
            f"{row['ratio_everywhere']:.3f}x everywhere, where shone "
            + ", ".join(f"{k} px {v:.3f}x" for k, v in row["ratio_where_shone"].items())
        )
    emit({"benchmark": "facets_where_shone", **found})


if __name__ == "__main__":
    main()
