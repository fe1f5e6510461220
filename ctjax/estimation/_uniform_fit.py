"""The paper's BRDF estimate over every frame of a capture (steps 2-4): one albedo, on the
ring S~ of every frame; and the checks and flags the albedo map's fit (`_map_fit.py`) shares."""

import dataclasses

import cv2
import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._determined import flag
from .._errors import CtjaxError
from .._frame_consistency import judge_frames_brightness
from .._model import ShadingModel
from .._result import Estimate, finite_or_none
from ..io import Capture
from ..io._field_of_view import black_frames
from ..lights import ColocatedLight
from ..lobes import Lambertian
from ..observations import Observations, usable_mask
from ..specular import MaskOptions, SpecularSets
from ._brdf import (
    LAMBERTIAN,
    PAPER,
    BRDFFamily,
    BRDFFit,
    brightness_sums,
    diffuse_alone,
    diffuse_note,
    fit_brdf,
)

# S and S~ as `ctjax masks` finds them by default.
DEFAULT_MASKS = MaskOptions()

# Relative standard error above which an estimate is reported as poorly determined.
WELL_DETERMINED = 0.05


def require_specular(capture: Capture, sets: list[SpecularSets], masks: MaskOptions) -> None:
    """Raises `CtjaxError` when no frame has a specular pixel, saying what there was."""
    if any(s.specular.any() for s in sets):
        return
    clipped = np.sum([s.clipped.sum(axis=(0, 1)) for s in sets], axis=0)
    pixels = sum(s.specular.size for s in sets)
    raise CtjaxError(
        f"{capture.root}: no specular pixels (S is empty) in any of {len(sets)} frame(s) "
        f"with {masks.highlights}; clipped channels outside S: "
        + ", ".join(f"{c} {n / pixels:.1%}" for c, n in zip("RGB", clipped, strict=True))
        + " of the pixels (--highlights, --min-speck)"
    )


def empty_ring_reason(capture: Capture, sets: list[SpecularSets], masks: MaskOptions) -> str:
    """Why no ring pixel can be fitted: what the pixels beside S lack (a normal, a view of
    the scene, an unclipped channel)."""
    near = valid = seen = measured = 0
    for frame, s in zip(capture.frames, sets, strict=True):
        distance = cv2.distanceTransform(
            (~s.specular).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE
        )
        beside = (distance <= masks.ring_px) & ~s.specular
        near += int(beside.sum())
        seen += int((beside & frame.visible).sum())
        beside &= frame.visible & frame.geometry_mask
        valid += int(beside.sum())
        measured += int((beside & ~s.saturated).sum())
    specular = sum(int(s.specular.sum()) for s in sets)
    head = f"the ring S~ is empty ({specular} specular pixels, {near} pixels within "
    head += f"{masks.ring_px} px of them"
    if seen == 0:
        return head + ", all outside the field of view or on overlays)"
    if valid == 0:
        return (
            head + f", {seen} in view, none with a valid normal: the shape has no depth "
            "beside the highlights (structure from motion finds no features on them; give "
            "depth/ or a wider ring, --ring-px)"
        )
    return (
        head + f", {valid} with a normal, every one with a clipped channel: the model cannot "
        "predict a value at the sensor's maximum (lower the exposure or the gain, or widen "
        "the ring, --ring-px)"
    )


def require_geometry(capture: Capture) -> None:
    missing = [f.name for f in capture.frames if f.normals is None]
    if missing:
        raise CtjaxError(
            f"{capture.root}: no depth or normals for frame(s) {', '.join(missing[:5])}; "
            "the BRDF fit needs the shape (add depth/ or normals/, or reconstruct it first; "
            "frames ctjax reconstruct did not register: leave them out, "
            "ctjax.io.registered_frames)"
        )
    empty = [f.name for f in capture.frames if not f.geometry_mask.any()]
    if len(empty) == len(capture.frames):
        raise CtjaxError(
            black_frames(capture) or f"{capture.root}: no pixel of any frame has a valid normal"
        )


def fit_to_json(fit, per_point: int | None = None) -> dict:
    """A BRDF fit's global parameters and weights with their standard errors (None where
    not finite), its RGB RMSE and cost: for the uniform fit (`BRDFFit`) and the albedo
    map's (`AlbedoMapFit`), whose weight `per_point` (rho_tilde, one per tracked point: its
    value here is a placeholder the caller replaces) has no standard error of its own."""
    out = {}
    weights, errors = np.asarray(fit.weights), np.asarray(fit.weights_stderr)
    for k, name in enumerate(fit.family.weight_names):
        out[name] = weights[k].tolist()
        if k != per_point:
            out[f"{name}_stderr"] = [finite_or_none(e) for e in errors[k]]
    params, params_stderr = np.asarray(fit.params), np.asarray(fit.params_stderr)
    half_width = np.asarray(fit.search_half_width)
    for d, name in enumerate(fit.family.names):
        out[name] = float(params[d])
        out[f"{name}_stderr"] = finite_or_none(params_stderr[d])
        out[f"{name}_search_half_width"] = float(half_width[d])
    out["rgb_rmse"] = float(fit.rgb_rmse)
    out["cost"] = float(fit.cost)
    return out


def clipping_to_json(capture) -> dict:
    """Where the fit's observations read as clipped: per channel, the level (linear, as the
    weights) at or above which a value is left out (`Capture.saturation`)."""
    return {
        "saturation": [float(level) for level in capture.saturation],
        "saturation_note": "per channel (R, G, B), the linear level from which an observation "
        "reads as clipped and is left out: 1.0 at full scale, lower where the channel stops "
        "following the others (the camera's ceiling)",
    }


def poorly_determined(fit, per_point: int | None = None) -> list[str]:
    """'name = value +- stderr' of each global parameter and weight channel whose standard
    error is above `WELL_DETERMINED` of its value (or not finite); an albedo map's weight
    `per_point` is not global and not judged here."""
    warnings = []
    for d, name in enumerate(fit.family.names):
        value, error = float(np.asarray(fit.params)[d]), float(np.asarray(fit.params_stderr)[d])
        if not np.isfinite(error) or error > WELL_DETERMINED * abs(value):
            warnings.append(f"{name} = {value:.4g} +- {error:.2g}")
    weights, errors = np.asarray(fit.weights), np.asarray(fit.weights_stderr)
    for k, name in enumerate(fit.family.weight_names):
        if k == per_point:
            continue
        for c, channel in enumerate("RGB"):
            if not np.isfinite(errors[k, c]) or errors[k, c] > WELL_DETERMINED * abs(weights[k, c]):
                warnings.append(f"{name}[{channel}] = {weights[k, c]:.4g} +- {errors[k, c]:.2g}")
    return warnings


# A frame with under this share of usable pixels adds little to a fit.
MIN_USABLE_SHARE = 0.05


def thin_frames(capture: Capture) -> list[str]:
    """A warning naming the frames with under `MIN_USABLE_SHARE` of their pixels usable
    (a normal, in view, no clipped channel)."""
    level = np.asarray(capture.saturation)
    shares = {f.name: usable_mask(f, level).mean() for f in capture.frames if f.normals is not None}
    thin = [f"{name} ({share:.1%})" for name, share in shares.items() if share < MIN_USABLE_SHARE]
    if not thin:
        return []
    return [
        f"frame(s) {', '.join(thin[:5])} have few usable pixels (a normal, in view, no "
        "clipped channel): they add little to the fit (check the depth, the exposure and "
        "the field of view: ctjax masks)"
    ]


def _zero_names(fit: BRDFFit) -> list[str]:
    """The weights that are 0 or within 2 standard errors of it, as "rho_tilde[R]"."""
    weights, errors = np.asarray(fit.weights), np.asarray(fit.weights_stderr)
    zero = (weights <= 0) | (weights <= 2 * np.nan_to_num(errors, nan=np.inf))
    return [
        f"{name}[{channel}]"
        for k, name in enumerate(fit.family.weight_names)
        for c, channel in enumerate("RGB")
        if zero[k, c]
    ]


def _at_zero(fit: BRDFFit) -> list[str]:
    """A warning for weights that cannot be told from 0: the data are explained without
    that term, which is no matter of the ring's width."""
    zero = _zero_names(fit)
    if not zero:
        return []
    return [
        f"{', '.join(zero)} cannot be told from 0 (within 2 standard errors, or at the "
        "nonnegativity bound): the data are explained without that term; for rho_tilde, "
        "the ring is dark or all specular (look at it: ctjax masks), for F_tilde, no "
        "highlight shapes the ring"
    ]


def fit_uniform(
    capture: "Capture | Observations",
    masks: MaskOptions = DEFAULT_MASKS,
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
    require_geometry(capture)
    sets = obs.sets
    require_specular(capture, sets, masks)
    specular_count = sum(int(s.specular.sum()) for s in sets)
    ring_count = sum(int(s.ring.sum()) for s in sets)
    if ring_count == 0:
        raise CtjaxError(f"{capture.root}: {empty_ring_reason(capture, sets, masks)}")
    samples = obs.ring()
    fit = fit_brdf(samples, family, tolerance=tolerance)
    lambertian = fit_brdf(samples, LAMBERTIAN)
    # The lobes' gain counts against the same diffuse term without them.
    plain = lambertian if family.diffuse is Lambertian else fit_brdf(samples, diffuse_alone(family))
    for result in (fit, lambertian, plain):
        if not np.all(np.isfinite(np.asarray(result.weights))) or not np.isfinite(
            float(result.cost)
        ):
            raise CtjaxError("the BRDF fit did not produce finite estimates")
    details = {
        **fit_to_json(fit),
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
        "model": "paper eq. (4): rho_tilde N.L/pi + F_tilde D(sigma)/(pi N.L N.V), L = V"
        + diffuse_note(family),
        "units": "weights linear (1.0 = 8-bit level 255); rgb_rmse in 8-bit levels",
        "lambertian": fit_to_json(lambertian),
        **({} if plain is lambertian else {"diffuse_alone": fit_to_json(plain)}),
        "masks": dataclasses.asdict(masks),
        **clipping_to_json(capture),
        "albedo": "uniform",
    }
    warnings = _at_zero(fit) + thin_frames(capture)
    poorly = [w for w in poorly_determined(fit) if w.split(" = ")[0] not in _zero_names(fit)]
    if poorly:
        warnings.append(
            f"the ring ({ring_count} pixels) is too thin to determine: {'; '.join(poorly)} "
            "(relative standard error above 5%); widen it with --ring-px"
        )
    estimate = Estimate(
        ShadingModel(fit.brdf, ColocatedLight()),
        {"calibration": float(fit.rgb_rmse)},
        warnings=warnings,
        details=details,
        cost=float(fit.cost),
    )
    estimate = flag_brdf_fit(estimate, fit, lambertian=plain)
    counts = [int(s.ring.sum()) for s in sets]
    _check_ring_brightness(estimate, fit, samples, counts, capture, tolerance)
    return estimate


def _check_ring_brightness(estimate, fit, samples, counts, capture, tolerance) -> None:
    """Each frame's brightness on its ring against the fit's prediction (one albedo: the
    gain g minimising sum |measured - g predicted|^2 over the frame's ring pixels), judged
    by `judge_frames_brightness`: the fit again with each frame's brightness undone (its
    ring's irradiance times g) where frames are off. On textured tissue each ring sees
    other tissue, so a frame can read off by its albedo alone: the albedo map's check
    (`ctjax fit --albedo map`, leave-one-out by surface point) tells the two apart."""
    across, power = brightness_sums(fit, samples)
    ends = np.cumsum(counts)
    brightness = {}
    for f, (end, n) in enumerate(zip(ends, counts, strict=True)):
        if n:
            total = float(np.sum(power[end - n : end]))
            brightness[f] = float(np.sum(across[end - n : end])) / total if total > 0 else np.nan
    ringed = [f for f, n in enumerate(counts) if n]

    def undone(gain):
        per_sample = np.repeat(gain[ringed], [counts[f] for f in ringed])
        irradiance = np.asarray(samples.irradiance) * per_sample
        again = fit_brdf(
            eqx.tree_at(
                lambda s: s.irradiance,
                samples,
                jnp.asarray(irradiance, samples.irradiance.dtype),
            ),
            fit.family,
            tolerance=tolerance,
        )
        return fitted_lobe(again), fit_to_json(again)

    judge_frames_brightness(
        estimate,
        brightness,
        [f.name for f in capture.frames],
        fitted_lobe(fit),
        undone if fit.family.names and len(ringed) > 1 else None,
        remedy="`ctjax fit --albedo map --effects frame_exposure` fits a gain per frame "
        "(the albedo map needs poses: `ctjax reconstruct`), as `calibrate-light` and "
        "`evaluate` with `--effects frame_exposure`",
        parameter=fit.family.names[0] if fit.family.names else "rho_tilde",
    )


def fitted_lobe(fit) -> dict[str, np.ndarray]:
    """A BnB fit's nonlinear parameters and its weights but the albedo's, by name: what a
    change of the frames' brightness must not move (`judge_frames_brightness`)."""
    lobe = {name: np.asarray(fit.params, float)[d] for d, name in enumerate(fit.family.names)}
    weights = np.asarray(fit.weights, float)
    for k, name in enumerate(fit.family.weight_names):
        if name != "rho_tilde":
            lobe[name] = weights[k]
    return lobe


def flag_brdf_fit(
    estimate: Estimate,
    fit: BRDFFit,
    per_point: int | None = None,
    lambertian: BRDFFit | None = None,
    halves: dict[str, BRDFFit] | None = None,
    gain: float | None = None,
) -> Estimate:
    """`estimate` flagged with what `fit` (the BnB's) does not determine
    (`ctjax._determined`): a lobe weight that cannot be told from 0, a roughness at the end
    of the family's box, a standard error that could not be computed. `per_point`: the
    weight estimated per surface point (the albedo map's), whose errors are not checked;
    `lambertian`: the same data's fit without the lobes, against which their gain counts;
    `halves`: the same fit on two halves of the frames ({"even_frames": fit, ...}), which a
    determined lobe's roughness must agree between. `gain`: the lobes' gain where measured
    otherwise (the albedo map's: where they show, `lobe_gain_where_it_shows`)."""
    family = fit.family
    weights, weights_stderr = np.asarray(fit.weights), np.asarray(fit.weights_stderr)
    params, params_stderr = np.asarray(fit.params), np.asarray(fit.params_stderr)
    values = {name: weights[k] for k, name in enumerate(family.weight_names)}
    values |= {name: float(params[d]) for d, name in enumerate(family.names)}
    stderrs = {
        name: weights_stderr[k] for k, name in enumerate(family.weight_names) if k != per_point
    }
    stderrs |= {name: float(params_stderr[d]) for d, name in enumerate(family.names)}
    ranges = {name: (family.lo[d], family.hi[d]) for d, name in enumerate(family.names)}
    if gain is None and lambertian is not None and float(lambertian.rgb_rmse) > 0:
        gain = 1 - float(fit.rgb_rmse) / float(lambertian.rgb_rmse)
    split = {
        name: tuple(float(np.asarray(h.params)[d]) for h in (halves or {}).values())
        for d, name in enumerate(family.names)
        if halves
    }
    estimate = flag(estimate, stderrs, ranges, values, gain, split)
    broad = [
        f"{name} = {float(params[d]):.3g}"
        for d, name in enumerate(family.names)
        if name.startswith("sigma") and float(params[d]) >= BROAD_LOBE
    ]
    if broad and not estimate.details.get("undetermined"):
        estimate.warnings.append(
            f"{BROAD_WARNING} ({', '.join(broad)}) is also what the light's cone looks like "
            "under the paper's light (at the lens, no falloff): `ctjax calibrate-light` fits "
            "the light's falloff with the lobe and says whether the lobe remains (on a real "
            "cholecystectomy video a lobe of sigma 0.39 that passed every check here was the "
            "spot falloff's: its gain fell from 1.1% to 0.04%)"
        )
    return estimate


# A lobe at least this broad (sigma) under the paper's light is checked against the light's
# falloff (`flag_brdf_fit`'s warning): cos^k about the axis and a Beckmann lobe of this width
# about N = H look alike where the tissue faces the scope.
BROAD_LOBE = 0.3
BROAD_WARNING = "a lobe this broad"
