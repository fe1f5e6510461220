"""`ctjax reconstruct`'s JSON report of a structure-from-motion reconstruction (the stereo
pairs' own is `_pairs.py`'s)."""

import numpy as np

from .._units import unit_of_reconstruction

SURFACE_MODEL = (
    "penalised cubic B-spline depth map per view (P-spline, thin-plate-like curvature "
    "penalty chosen by block cross-validation, Tukey-robust), fitted to the points of all "
    "frames; normals from its analytic derivatives"
)

# Below this baseline (the largest distance between registered cameras, relative to the
# working distance), reconstruct warns of little parallax.
MIN_BASELINE = 0.02


def _baseline(views, scale_info) -> float | None:
    """The largest distance between two registered cameras over the reference frame's
    median depth (None with fewer than two)."""
    centres = np.array([view.pose[:3, 3] for view in views.values()])
    depth = scale_info["median_reference_depth"] * scale_info["factor"]
    if len(centres) < 2 or not np.isfinite(depth) or depth <= 0:
        return None
    spread = np.linalg.norm(centres[:, None] - centres[None], axis=-1).max()
    return float(spread / depth)


def reconstruction_report(
    sparse, views, reference, points, scale_info, counts, knot_spacing_px
) -> dict:
    """`ctjax reconstruct`'s JSON report."""
    coverage = {name: float(view.hull.mean()) for name, view in views.items()}
    unregistered = [n for n in sparse.names if n not in views]
    warnings = [
        f"frame {n} did not register (skipped; no depth or normals for it)" for n in unregistered
    ]
    if not scale_info["metric"]:
        warnings.append(
            "depth is up to scale (unit: median depth of the reference frame); give "
            "--scale-mm or --volume-mm3 (scale_mm=, volume_mm3= in Python) for millimetres"
        )
    baseline = _baseline(views, scale_info)
    if baseline is not None and baseline < MIN_BASELINE:
        warnings.append(
            f"little parallax: the registered cameras are at most {baseline:.1%} of the "
            "working distance apart, and depth from so short a baseline is poorly "
            "determined (move the camera more between frames)"
        )
    report = {
        "frames": len(sparse.names),
        "registered": [n for n in sparse.names if n in views],
        "unregistered": unregistered,
        "reference_frame": reference,
        "points": len(sparse.points),
        "mean_reprojection_error_px": sparse.mean_reprojection_error,
        "mean_track_length": float(np.mean(sparse.track_lengths)) if len(points) else 0.0,
        "coverage": float(np.mean(list(coverage.values()))) if coverage else 0.0,
        "coverage_per_frame": coverage,
        "baseline_over_depth": _baseline(views, scale_info),
        "keypoints": sparse.keypoints,
        "matching": sparse.matching,
        "scale": scale_info,
        "length_unit": unit_of_reconstruction({"scale": scale_info}),
        "surface": {
            "model": SURFACE_MODEL,
            "knot_spacing_px": float(knot_spacing_px),
            "points_per_frame": counts,
            "residual_rms_per_frame": {n: v.surface.residual_rms for n, v in views.items()},
        },
        "world_frame": f"camera frame of {reference} (its pose is the identity)",
        "warnings": warnings,
    }
    return report
