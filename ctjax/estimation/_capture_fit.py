"""`ctjax fit`: the paper's BRDF estimate over every frame of a capture (steps 2-4)."""

import dataclasses

import numpy as np

from .._errors import CtjaxError
from .._model import ShadingModel
from .._result import Estimate
from ..io import Capture
from ..lights import ColocatedLight
from ..observations import Observations
from ._brdf import LAMBERTIAN, PAPER, BRDFFamily, BRDFFit, fit_brdf
from ._specular_set import (
    DEFAULT_LIGHTNESS,
    DEFAULT_MIN_SPECK_PX,
    DEFAULT_RING_PX,
    DEFAULT_SATURATION,
    SpecularSets,
    specular_sets,
)

# Relative standard error above which an estimate is reported as poorly determined.
_WELL_DETERMINED = 0.05


@dataclasses.dataclass(frozen=True)
class MaskOptions:
    lightness: float = DEFAULT_LIGHTNESS
    saturation: float = DEFAULT_SATURATION
    ring_px: float = DEFAULT_RING_PX
    min_speck_px: int = DEFAULT_MIN_SPECK_PX


def capture_sets(capture: Capture, options: MaskOptions = MaskOptions()) -> list[SpecularSets]:
    """S, S~ and the saturated pixels of every frame (pixels without a normal, and outside
    the frame's field of view, excluded).

    Raises `CtjaxError` for a frame whose every pixel is saturated (nothing to fit).
    """
    for frame in capture.frames:
        if np.all(np.max(frame.image, axis=-1) >= 1.0):
            raise CtjaxError(
                f"{capture.root}: frame {frame.name}: every pixel is saturated (at full scale); "
                "an over-exposed image carries no shading"
            )
    return [
        specular_sets(
            frame.image,
            frame.geometry_mask,
            lightness=options.lightness,
            saturation=options.saturation,
            ring_px=options.ring_px,
            min_speck_px=options.min_speck_px,
            visible=frame.visible,
        )
        for frame in capture.frames
    ]


def _require_geometry(capture: Capture) -> None:
    missing = [f.name for f in capture.frames if f.normals is None]
    if missing:
        raise CtjaxError(
            f"{capture.root}: no depth or normals for frame(s) {', '.join(missing[:5])}; "
            "the BRDF fit needs the shape (add depth/ or normals/, or reconstruct it first)"
        )
    empty = [f.name for f in capture.frames if not f.geometry_mask.any()]
    if len(empty) == len(capture.frames):
        raise CtjaxError(f"{capture.root}: no pixel of any frame has a valid normal")


def _fit_to_json(fit: BRDFFit) -> dict:
    out = {}
    weights = np.asarray(fit.weights)
    weights_err = np.asarray(fit.weights_stderr)
    for k, name in enumerate(fit.family.weight_names):
        out[name] = weights[k].tolist()
        out[f"{name}_stderr"] = weights_err[k].tolist()
    for d, name in enumerate(fit.family.names):
        out[name] = float(fit.params[d])
        out[f"{name}_stderr"] = float(fit.params_stderr[d])
        out[f"{name}_search_half_width"] = float(fit.search_half_width[d])
    out["rgb_rmse"] = float(fit.rgb_rmse)
    out["cost"] = float(fit.cost)
    return out


def _poorly_determined(fit: BRDFFit) -> list[str]:
    warnings = []
    for d, name in enumerate(fit.family.names):
        value, error = float(fit.params[d]), float(fit.params_stderr[d])
        if not np.isfinite(error) or error > _WELL_DETERMINED * abs(value):
            warnings.append(f"{name} = {value:.4g} +- {error:.2g}")
    weights, errors = np.asarray(fit.weights), np.asarray(fit.weights_stderr)
    for k, name in enumerate(fit.family.weight_names):
        for c, channel in enumerate("RGB"):
            if not np.isfinite(errors[k, c]) or errors[k, c] > _WELL_DETERMINED * abs(
                weights[k, c]
            ):
                warnings.append(f"{name}[{channel}] = {weights[k, c]:.4g} +- {errors[k, c]:.2g}")
    return warnings


ALBEDO_CHOICES = ("map", "uniform")


def default_albedo(capture: "Capture | Observations") -> str:
    """`"map"` when the capture has several frames, all with depth and a pose (the albedo
    map follows surface points across them), else `"uniform"` (the paper's model)."""
    frames = capture.frames
    if len(frames) > 1 and all(f.pose is not None and f.depth is not None for f in frames):
        return "map"
    return "uniform"


def fit_capture(
    capture: "Capture | Observations",
    masks: MaskOptions = MaskOptions(),
    family: BRDFFamily = PAPER,
    *,
    tolerance: float = 1e-3,
    albedo: str | None = None,
    max_points: int | None = None,
) -> Estimate:
    """Estimate the BRDF of a capture: the paper's light (co-located with the camera,
    L = V) and its model (`family`) by default.

    `albedo="map"` (the default when every frame has depth and a pose, `default_albedo`):
    one rho_tilde per surface point and channel, with F_tilde and sigma shared, from all
    frames (`fit_albedo_map`): the estimate for textured tissue. `albedo="uniform"`: the
    paper's model, one rho_tilde, fitted on the ring S~ of every frame (below).
    """
    albedo = default_albedo(capture) if albedo is None else albedo
    if albedo not in ALBEDO_CHOICES:
        raise CtjaxError(f"albedo must be one of {ALBEDO_CHOICES}, got {albedo!r}")
    if albedo == "map":
        from ._map_fit import fit_albedo_map

        return fit_albedo_map(capture, masks, family, tolerance=tolerance, max_points=max_points)
    return fit_uniform(capture, masks, family, tolerance=tolerance)


def fit_uniform(
    capture: "Capture | Observations",
    masks: MaskOptions = MaskOptions(),
    family: BRDFFamily = PAPER,
    *,
    tolerance: float = 1e-3,
) -> Estimate:
    """The paper's estimate: detect S and S~ in every frame and fit the BRDF, one albedo,
    on the ring of all frames.

    The paper's light (co-located with the camera, L = V) and its model by default. Returns
    an `Estimate` of the `ShadingModel` (the BRDF under `ColocatedLight`) whose JSON is what
    `ctjax fit` writes (no timings, so that the same capture gives the same bytes):
    `rmse["calibration"]` is the ring's RMSE; `details` hold the standard errors, the ring
    and specular pixel counts per frame and the Lambertian fit of the same ring. Raises
    `CtjaxError` when there is no specular pixel, the ring is empty or the fit failed to
    produce finite numbers.
    """
    obs = Observations.of(capture, masks)
    capture = obs.capture
    _require_geometry(capture)
    sets = obs.sets
    specular_count = sum(int(s.specular.sum()) for s in sets)
    ring_count = sum(int(s.ring.sum()) for s in sets)
    if specular_count == 0:
        saturated = sum(int(s.saturated.sum()) for s in sets)
        raise CtjaxError(
            f"{capture.root}: no specular pixels (S is empty) in any of {len(sets)} frame(s) "
            f"at lightness >= {masks.lightness}, saturation <= {masks.saturation}"
            + (f"; {saturated} saturated coloured pixels" if saturated else "")
        )
    if ring_count == 0:
        raise CtjaxError(
            f"{capture.root}: the ring S~ is empty ({specular_count} specular pixels, but none "
            f"of their neighbours within {masks.ring_px} px is unsaturated with a valid normal); "
            "try a wider ring (--ring-px)"
        )
    samples = obs.ring()
    fit = fit_brdf(samples, family, tolerance=tolerance)
    lambertian = fit_brdf(samples, LAMBERTIAN)
    for result in (fit, lambertian):
        if not np.all(np.isfinite(np.asarray(result.weights))) or not np.isfinite(
            float(result.cost)
        ):
            raise CtjaxError("the BRDF fit did not produce finite estimates")
    details = {
        **_fit_to_json(fit),
        "n_ring_pixels": ring_count,
        "n_specular_pixels": specular_count,
        "frames": [
            {
                "name": f.name,
                "specular_pixels": int(s.specular.sum()),
                "ring_pixels": int(s.ring.sum()),
                "saturated_pixels": int(s.saturated.sum()),
            }
            for f, s in zip(capture.frames, sets, strict=True)
        ],
        "model": "paper eq. (4): rho_tilde N.L/pi + F_tilde D(sigma)/(pi N.L N.V), L = V",
        "units": "weights linear (1.0 = 8-bit level 255); rgb_rmse in 8-bit levels",
        "lambertian": _fit_to_json(lambertian),
        "masks": dataclasses.asdict(masks),
        "albedo": "uniform",
    }
    warnings = []
    poorly = _poorly_determined(fit)
    if poorly:
        warnings.append(
            f"the ring ({ring_count} pixels) is too thin to determine: {'; '.join(poorly)} "
            "(relative standard error above 5%); widen it with --ring-px"
        )
    return Estimate(
        ShadingModel(fit.brdf, ColocatedLight()),
        {"calibration": float(fit.rgb_rmse)},
        warnings=warnings,
        details=details,
        cost=float(fit.cost),
    )
