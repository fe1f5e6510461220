"""`ctjax fit --albedo map`: the BRDF of textured tissue, one albedo per surface point.

Surface points near the highlights (and as many elsewhere) are followed across every frame by
depth and poses (`Observations.tracks`), the BRDF is fitted with every point's albedo
eliminated in closed form (`fit_brdf_map`), and each frame's albedo map is then estimated
from all frames given the fitted lobes (`albedo_maps`).
"""

import dataclasses
import json

import numpy as np

from .._errors import CtjaxError
from .._model import ShadingModel
from .._result import Estimate
from .._tracks import DEFAULT_NEIGHBOURS, require_poses
from ..lights import ColocatedLight
from ..observations import Observations
from ._albedo_map import albedo_maps, fit_brdf_map, track_shading
from ._brdf import LAMBERTIAN, PAPER, BRDFFamily
from ._capture_fit import (
    _WELL_DETERMINED,
    MaskOptions,
    _require_geometry,
    require_specular,
    thin_frames,
)
from ._sensitivity import specular_change


def _number(value):
    value = float(value)
    return value if np.isfinite(value) else None


def _map_fit_json(fit, per_point: int) -> dict:
    out = {}
    weights, errors = np.asarray(fit.weights), np.asarray(fit.weights_stderr)
    for k, name in enumerate(fit.family.weight_names):
        out[name] = weights[k].tolist()
        if k != per_point:
            out[f"{name}_stderr"] = [_number(e) for e in errors[k]]
    for d, name in enumerate(fit.family.names):
        out[name] = float(fit.params[d])
        out[f"{name}_stderr"] = _number(fit.params_stderr[d])
        out[f"{name}_search_half_width"] = float(fit.search_half_width[d])
    out["rgb_rmse"] = float(fit.rgb_rmse)
    out["cost"] = float(fit.cost)
    return out


def _poorly_determined(fit, per_point: int) -> list[str]:
    warnings = []
    for d, name in enumerate(fit.family.names):
        value, error = float(fit.params[d]), float(fit.params_stderr[d])
        if not np.isfinite(error) or error > _WELL_DETERMINED * abs(value):
            warnings.append(f"{name} = {value:.4g} +- {error:.2g}")
    weights, errors = np.asarray(fit.weights), np.asarray(fit.weights_stderr)
    for k, name in enumerate(fit.family.weight_names):
        if k == per_point:
            continue
        for c, channel in enumerate("RGB"):
            if not np.isfinite(errors[k, c]) or errors[k, c] > _WELL_DETERMINED * abs(
                weights[k, c]
            ):
                warnings.append(f"{name}[{channel}] = {weights[k, c]:.4g} +- {errors[k, c]:.2g}")
    return warnings


def _median_albedo(capture, maps) -> np.ndarray:
    """The maps' median albedo per channel (NaN where that channel clipped ignored)."""
    median = np.zeros(3)
    for c in range(3):  # one channel at a time: bounded memory at 1080p
        values = np.concatenate([m[..., c][np.isfinite(m[..., c])] for m in maps])
        if values.size == 0:
            raise CtjaxError(f"{capture.root}: no pixel's albedo could be estimated in {'RGB'[c]}")
        median[c] = np.median(values)
        del values
    return median


def _normal_sensitivity(capture, fit, shading, per_point: int) -> dict:
    """How much the fitted specular changes per degree of normal error where it is
    measured (`_sensitivity.py`), and whether the normals come from `ctjax reconstruct`."""
    change, count = specular_change(
        fit.family, fit.params, shading, fit.weights, fit.albedo, per_point
    )
    root = getattr(capture, "root", None)
    report = root / "reconstruction.json" if root else None
    from_reconstruct = bool(report and report.is_file())
    refined = False
    if from_reconstruct:
        try:
            refined = bool(json.loads(report.read_text())["surface"]["shading"]["refined"])
        except (ValueError, KeyError, TypeError):
            refined = False
    return {
        "specular_change_per_degree": _number(change),
        "observations": int(count),
        "normals_from_reconstruct": from_reconstruct,
        "refined_by_the_shading": refined,
        "note": "median relative change of the fitted global lobes when every normal is "
        "tilted 1 degree away from its half vector, over the tracked observations where they "
        "are at least 10% of the model",
    }


def _warnings(capture, fit, per_point: int, points: int, coverage, sensitivity) -> list[str]:
    """Poorly determined parameters, frames with few usable pixels, frames the map covers
    thinly, and normals from SfM where the specular is sensitive to them."""
    warnings = thin_frames(capture)
    change = sensitivity["specular_change_per_degree"]
    from_sfm = sensitivity["normals_from_reconstruct"] and not sensitivity["refined_by_the_shading"]
    if from_sfm and change is not None and change > 0.05:
        warnings.append(
            "the normals come from ctjax reconstruct (not refined by the shading, --shading): "
            "around the highlights they are "
            f"typically 1-5 degrees off, and there the fitted specular changes by {change:.0%} "
            "per degree (the lobe is read on its tails where the core is clipped): sigma and "
            "F_tilde may be off by tens of percent (README, 'Shape from images')"
        )
    poorly = _poorly_determined(fit, per_point)
    if poorly:
        warnings.append(
            f"{points} tracked points cannot determine: {'; '.join(poorly)} (relative "
            "standard error above 5%)"
        )
    thin = [f.name for f, c in zip(capture.frames, coverage, strict=True) if c < 0.9]
    if thin:
        warnings.append(
            f"albedo map covers under 90% of the surface in frame(s) {', '.join(thin[:5])} "
            "(clipped, or seen in no other frame: check the poses and depth)"
        )
    return warnings


def fit_albedo_map(
    capture,
    masks: MaskOptions | None = None,
    family: BRDFFamily = PAPER,
    *,
    tolerance: float = 1e-3,
    max_points: int | None = None,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
) -> Estimate:
    """The BRDF with an albedo map (see the module doc), under the paper's light (L = V).

    Returns an `Estimate` of the `ShadingModel` whose `rho_tilde` is the median of the
    albedo maps per channel; `arrays["albedo/NAME"]` is frame NAME's map (H, W, 3),
    rho_tilde per pixel in the same linear units, NaN where not estimated;
    `rmse["calibration"]` the RMSE (8-bit levels) over every observation of the tracked
    points; `details` the standard errors of the global parameters (albedos eliminated), the
    counts, the maps' coverage and the Lambertian fit of the same tracks (with its own map).
    `max_points` bounds the tracked points (`Observations.tracks`), `neighbours` the frames
    each point is looked for in (nearest in camera position; all when None).
    """
    masks = MaskOptions() if masks is None else masks
    obs = Observations.of(capture, masks)
    capture = obs.capture
    _require_geometry(capture)
    require_poses(capture)
    sets = obs.sets
    require_specular(capture, sets, masks)
    per_point = family.weight_names.index("rho_tilde")
    options = {} if max_points is None else {"max_points": max_points}
    tracks = obs.tracks(neighbours=neighbours, **options)
    views = tracks.views
    shading = track_shading(tracks)
    fit = fit_brdf_map(shading, family, tolerance=tolerance)
    lambertian = fit_brdf_map(shading, LAMBERTIAN)
    for result in (fit, lambertian):
        if not np.all(np.isfinite(np.asarray(result.weights))) or not np.isfinite(
            float(result.cost)
        ):
            raise CtjaxError("the BRDF fit with an albedo map did not produce finite estimates")
    maps, counts = albedo_maps(capture, fit.brdf, per_point=per_point, neighbours=neighbours)
    median = _median_albedo(capture, maps)
    weights = np.asarray(fit.weights).copy()
    weights[per_point] = median
    brdf = fit.brdf.with_weights(weights.astype(np.asarray(fit.weights).dtype))
    coverage = [
        float(np.mean(np.all(np.isfinite(m), -1)[f.geometry_mask])) if f.geometry_mask.any() else 0
        for m, f in zip(maps, capture.frames, strict=True)
    ]
    details = {
        **_map_fit_json(fit, per_point),
        "rho_tilde": median.tolist(),
        "albedo": "map",
        "albedo_note": "rho_tilde is the median of the albedo maps per channel; the maps hold "
        "rho_tilde per pixel (`ctjax fit --albedo-maps DIR`)",
        "n_points": len(tracks),
        "n_observations": int(tracks.observed.sum()),
        "n_points_seen_twice": int(np.sum(views > 1)),
        "n_specular_pixels": sum(int(s.specular.sum()) for s in sets),
        "frames": [
            {
                "name": f.name,
                "specular_pixels": int(s.specular.sum()),
                "albedo_coverage": cov,
                "median_views": float(np.median(c[c > 0])) if np.any(c > 0) else 0.0,
            }
            for f, s, cov, c in zip(capture.frames, sets, coverage, counts, strict=True)
        ],
        "model": "eq. (4) with rho_tilde per surface point: rho_tilde(p) N.L/pi + F_tilde "
        "D(sigma)/(pi N.L N.V), L = V",
        "units": "weights linear (1.0 = 8-bit level 255); rgb_rmse in 8-bit levels",
        "lambertian": {**_map_fit_json(lambertian, 0), "albedo": "map"},
        "normals": _normal_sensitivity(capture, fit, shading, per_point),
        "masks": dataclasses.asdict(masks),
    }
    warnings = _warnings(capture, fit, per_point, len(tracks), coverage, details["normals"])
    arrays = {f"albedo/{f.name}": m for f, m in zip(capture.frames, maps, strict=True)}
    return Estimate(
        ShadingModel(brdf, ColocatedLight()),
        {"calibration": float(fit.rgb_rmse)},
        warnings=warnings,
        details=details,
        arrays=arrays,
        cost=float(fit.cost),
    )
