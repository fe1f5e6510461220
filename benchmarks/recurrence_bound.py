"""How far could a lobe that remembers where each point shone take `evaluate`'s ratio, and
where does the lobe about each point's own facet take its gain?

    python benchmarks/recurrence_bound.py CAPTURE [--calib N]

`ctjax evaluate --no-sfs --facets on`'s protocol (the near light fitted on the first 60% of
the frames; every test view of a tracked point predicted from the point's other views,
`ctjax.heldout.HeldOutTracks`). A test view is within r px of S where its pixel is within r
px of its frame's specular set (`Observations.specular_distance`); its point "shone" where
another of its views (any frame: the facet protocol reads a view's facet from the point's
other views) lies within r px of S there. Prints, for Lambert's model
under Cook-Torrance's light, the ratio its RMSE would fall to if the test views within r px
of S (all of them, or only those whose point shone) were predicted as well as the views 20
px or more from S are, everything else left as it is: what a lobe that knows where each
point shone (the facets, read from the calibration views) can take from the highlights
themselves. It is not a floor for every lobe: a lobe also changes each point's albedo,
fitted to the point's other views, and with it the error away from the highlights. Then
the facet lobe's squared residual against Lambert's, by the distance to S and by whether
the point shone (3 px): where its gain lies.

Measured (2026-12-05, c80d415; 640 px; 60% of the frames calibrating), of Lambert's squared
residual on the test views in S at points with another view within 3 px of S, the share the
facet lobe takes: SCARED 61-84 54% (the facet lobe 0.723x; views 0.016 rad apart in H), the
second sinus video's A at every 2nd frame 44% (1.000x; 0.011 rad), at every 3rd frame 33%
(0.992x, 0.011 rad; measured later that day at 427f86c), at every 5th frame 13%
(0.966x; 0.031 rad), the shared cholecystectomy 6% (0.983x; 0.076 rad). The bound at 3 px
over those points: 0.668x, 0.826x, 0.848x, 0.800x. docs/real-video.md, "Where the facet
lobe's gain lies" (the table).

Slow (the near light and the facets as `evaluate` fits them: 4-5 minutes on 2 cores): a
benchmark, not a test.
"""

import argparse

import jax
import numpy as np
from _results import emit
from sparkle_recurrence import distance_to_s

FAR_PX = 20
RADII_PX = (1, 3, 7)


def _shone_in_another_view(near) -> np.ndarray:
    """(M, P): whether another view of the same point (any frame, the judged one aside) is
    near S, as `near` (M, P) says: what the facet protocol can read a view's facet from."""
    return (near.sum(axis=0)[None, :] - near) > 0


def _table(residual, weight, distance, shone_by_radius) -> dict:
    """A model's judged test views (residual (C, M, P) levels, weight (M, P)): RMSE, what
    it leaves 20 px or more from S, and per radius the views within it of S, their share
    of the squared residual and the bounds (see the module)."""
    squared = weight * np.mean(residual**2, axis=0)  # (M, P)
    judged = weight > 0
    total = weight[judged].sum()
    rmse = float(np.sqrt(squared[judged].sum() / total))
    far = judged & (distance >= FAR_PX)
    floor = squared[far].sum() / weight[far].sum()  # per unit weight
    row = {"rmse": rmse, "far_rmse": float(np.sqrt(floor)), "squared": squared}

    def bound(replaced):
        kept = squared[judged & ~replaced].sum() + floor * weight[replaced].sum()
        return float(np.sqrt(kept / total) / rmse)

    for radius in RADII_PX:
        near = judged & (distance < radius)
        recurring = near & shone_by_radius[radius]
        row[f"within_{radius}px"] = {
            "views": float(weight[near].sum() / total),
            "share": float(squared[near].sum() / squared[judged].sum()),
            "bound": bound(near),
            "shone": float(weight[recurring].sum() / weight[near].sum()),
            "bound_shone": bound(recurring),
        }
    return row


def bounds(root, calibration: int | None = None) -> dict:
    from ctjax._performance import enable_compilation_cache
    from ctjax.evaluation import evaluate
    from ctjax.fitting import FACET_CANDIDATES, facet_heldout
    from ctjax.fitting._facets import FACET_REFINE_STEPS, facet_model
    from ctjax.fitting._map_least_squares import heldout_map_residuals
    from ctjax.heldout import HeldOutTracks
    from ctjax.io import load_capture
    from ctjax.observations import Observations

    enable_compilation_cache()
    observations = Observations.of(load_capture(root))
    evaluation = evaluate(observations.capture, calibration=calibration, sfs=False, facets=True)
    calib = evaluation.calibration_frames
    tracks = HeldOutTracks.split(observations, len(calib))
    test = tracks.test
    distance = distance_to_s(observations, test)
    shone = {r: _shone_in_another_view(distance < r) for r in RADII_PX}
    out = {"capture": str(root), "frames": len(observations), "calibration_frames": len(calib)}
    same_light = evaluation.lambertian_same_light or evaluation.lambertian
    for name, estimate in (
        ("lambert_same_light", same_light),
        ("cook_torrance", evaluation.cook_torrance),
    ):
        model = tracks.with_heldout_frames(estimate.model)
        residual, weight = heldout_map_residuals(model, test, tracks.judged)
        out[name] = _table(residual, weight, distance, shone)
    # The facet lobe as `evaluate` chose it, each judged view's residual (`facet_heldout`).
    facets = evaluation.facets
    frames = observations.capture.frames
    rotations = np.stack([np.asarray(f.pose, float)[:3, :3] for f in frames])
    light = evaluation.cook_torrance.model.light
    across = FACET_CANDIDATES[facets["candidates"]]
    lobe = facet_heldout(
        facet_model(light, facets["sigma"], facets["F_tilde"]), test, tracks.judged, rotations,
        refine_steps=FACET_REFINE_STEPS, across=across,
    )  # fmt: skip
    out["facet_lobe"] = _table(lobe.residual, lobe.weight, distance, shone)
    out["facet_lobe"] |= {"sigma": facets["sigma"], "F_tilde": facets["F_tilde"]}
    out["facet_lobe"]["status"] = facets["status"]
    lambert = out["lambert_same_light"]
    for name in ("cook_torrance", "facet_lobe"):
        out[name]["ratio"] = out[name]["rmse"] / lambert["rmse"]
    # Where the facet lobe's gain lies: Lambert's squared residual against the lobe's, by
    # the view's distance to S and whether another view of its point is within 3 px of S.
    before, after = lambert["squared"], out["facet_lobe"]["squared"]
    total = before.sum()
    gain = {}
    for low, high in ((0, 1), (1, 3), (3, 7), (7, FAR_PX), (FAR_PX, np.inf)):
        band = (distance >= low) & (distance < high)
        for key, where in (("shone", band & shone[3]), ("not_shone", band & ~shone[3])):
            name = f"{low:g}-{high:g} px, {key}"
            gain[name] = (float(before[where].sum() / total), float(after[where].sum() / total))
    out["facet_lobe"]["by_band"] = gain
    # The facet lobe's prediction only where another view of the point shone (3 px), Lambert's
    # elsewhere (a view whose point shows no highlight in its other views takes no facet).
    kept = np.where(shone[3], after, before)
    out["facet_lobe"]["only_points_that_shone_ratio"] = float(np.sqrt(kept.sum() / total))
    for name in ("lambert_same_light", "cook_torrance", "facet_lobe"):
        del out[name]["squared"]
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", help="a reconstructed capture (depth, normals, poses)")
    parser.add_argument("--calib", type=int, default=None, help="calibration frames (60%% of them)")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    found = bounds(args.capture, args.calib)
    print(
        f"{found['capture']}: {found['frames']} frames, {found['calibration_frames']} calibrating"
    )
    lambert = found["lambert_same_light"]
    print(
        f"  test RMSE (levels): Lambert under the same light {lambert['rmse']:.2f} ({FAR_PX} px "
        f"or more from S {lambert['far_rmse']:.2f}), Cook-Torrance "
        f"{found['cook_torrance']['ratio']:.3f}x, the facet lobe "
        f"{found['facet_lobe']['ratio']:.3f}x"
    )
    print("  Lambert's, with the views near S predicted as well as those far from S:")
    for radius in RADII_PX:
        r = lambert[f"within_{radius}px"]
        print(
            f"    within {radius} px of S ({r['views']:.1%} of the views, {r['share']:.1%} of the "
            f"squared residual): all {r['bound']:.3f}x; those with another view of their point "
            f"within {radius} px of S ({r['shone']:.1%} of them) {r['bound_shone']:.3f}x"
        )
    facet = found["facet_lobe"]
    print(
        f"  the facet lobe (sigma {facet['sigma']:.3f}, F_tilde {facet['F_tilde']:.4f}, "
        f"{facet['status']}): Lambert's squared residual -> the lobe's (shares of Lambert's "
        "total) by the distance to S and whether another view of the point is within 3 px of "
        "S:"
    )
    for band, (before, after) in facet["by_band"].items():
        print(f"    {band:>22}: {before:.3f} -> {after:.3f}")
    print(
        "  the facet lobe only where another view of the point is within 3 px of S (Lambert "
        "elsewhere): "
        f"{facet['only_points_that_shone_ratio']:.3f}x"
    )
    emit({"benchmark": "recurrence_bound", **found})


if __name__ == "__main__":
    main()
