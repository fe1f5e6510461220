"""Whether the data determine an estimate: the statuses a converged fit can still deserve.

A solver that converged has found the best parameters of its model for the data; that is
not a measurement of each parameter. On real frames three things happen that a reader of
`"status": "successful"` would not guess, and each gets its own `Status`:

- `no_lobe`: a specular lobe whose weight F_tilde cannot be told from 0 (its chi-square
  over the channels within the 95% quantile, or at the nonnegativity bound), or that lowers
  the RMSE by under 0.5% against the model without it where it shows (predicts at least
  one 8-bit level; over every observation a well-determined lobe can bring less: few
  highlights, mostly clipped), or whose colour is not the light's
  (its least channel under a quarter of its greatest: a highlight reflects the light's
  colour; on a real sinus video a fit put F_tilde at [0, 0.033, 0.035]). The data are
  explained without a highlight lobe, and its roughness sigma is not determined.
- `at_bound`: a roughness at the end of its search range: within 2% of either end of the
  paper's (0, 1], or near or above 1 where a range is opened; or another searched parameter
  (a diffuse term's shape, `oren_nayar_roughness`) within 2% of either end of its range.
  At the top, the lobe explains a broad angular trend (a falloff, vignetting, the camera's
  response, a non-Lambertian diffuse term), not a highlight; at the bottom, a lobe sharper than the
  data resolve. Its standard error, computed at the bound, means nothing.
- `unstable`: a roughness that two halves of the frames (even and odd) put more than 20%
  apart: the fit's own standard error, small as it may be, does not measure that (on real
  video one segment's halves gave sigma 0.28 and 0.82).
- `imprecise`: a roughness whose standard error is over a quarter of its value (its 95%
  interval spans half to one and a half times it): on 24 frames of a real sinus video the
  near light's fit read sigma 0.048 +- 0.016 from a lobe that showed on 75 of its views.
- `no_standard_error`: a parameter whose standard error could not be computed (the
  Jacobian is rank-deficient there): the data do not constrain it.

`undetermined(values, stderrs)` lists them from an estimate's named parameters (the
paper's words: `F_tilde`, `sigma`, `F_tilde_2`...) and their standard errors; `flag`
writes them into an `Estimate`: its status (when the solve itself succeeded), a warning
per parameter, and `details["undetermined"]`.
"""

import dataclasses
import math

import numpy as np

from ._status import Status

# The paper's search range of the roughness, (0, 1]; a roughness within EDGE of the range's
# width from either end is at its bound, and one at or above TREND is no highlight lobe.
PAPER_ROUGHNESS_RANGE = (0.0, 1.0)
EDGE = 0.02
TREND = 1.0 - EDGE
# A lobe's weights cannot be told from 0 when their joint chi-square, sum (F_c / se_c)^2
# over the channels, is at most this: the 95% quantile of chi-square with 3 degrees of
# freedom (each channel within 2 standard errors would pass one channel in 7 by chance).
CHI2_3_95 = 7.815
# ... nor when it lowers the RMSE by less than this share against the model without it,
# where it shows (`ctjax.fitting.lobe_gain_where_it_shows`).
MIN_LOBE_GAIN = 0.005
# A specular reflection has the light's colour (the dichromatic model; tissue's Fresnel
# coefficient barely changes over the visible range): a lobe whose least channel is under
# this share of its greatest, by more than 2 standard errors, explains something else.
MIN_LOBE_WHITENESS = 0.25
# Roughness parameters by the prefix of their paper name, and the lobe weights beside them.
ROUGHNESS = ("sigma", "alpha")
LOBE_WEIGHT = "F_tilde"
# Differences beyond this many standard errors are not noise.
SIGNIFICANCE = 2.0
# Two halves of the frames agree on a roughness within this share of their mean.
HALVES_AGREE = 0.2
# A roughness is measured only where its standard error is at most this share of it.
MAX_RELATIVE_ERROR = 0.25
# Where several apply, the status reported is the first of these.
PRIORITY = (
    Status.no_lobe,
    Status.at_bound,
    Status.unstable,
    Status.imprecise,
    Status.no_standard_error,
)


@dataclasses.dataclass(frozen=True)
class Undetermined:
    """One parameter the data do not determine: its name, the status, why (a sentence)."""

    parameter: str
    status: Status
    reason: str

    def to_json(self) -> dict:
        return {"parameter": self.parameter, "status": self.status.name, "reason": self.reason}


def rmse_change(gain: float) -> str:
    """`gain` (the RMSE's relative fall) in words: "lowers the RMSE by 0.16%", or "raises
    the RMSE by 15.71%" where it is negative (the lobe made those views worse)."""
    verb = "lowers" if not gain < 0 else "raises"
    return f"{verb} the RMSE by {abs(100 * gain):.2f}%"


def _suffix(name: str, prefix: str) -> str | None:
    """`"_2"` for `F_tilde_2` and prefix `F_tilde`; `""` for the name itself; None else."""
    if name == prefix:
        return ""
    rest = name.removeprefix(prefix)
    return rest if rest != name and rest.startswith("_") and rest[1:].isdigit() else None


def _array(value) -> np.ndarray | None:
    if value is None:
        return None
    array = np.asarray(value, dtype=object)
    return np.asarray([np.nan if v is None else float(v) for v in array.reshape(-1)], float)


def _coloured(weight: np.ndarray, error: np.ndarray | None) -> bool:
    """A lobe weight (3,) far from the light's colour: its least channel under
    `MIN_LOBE_WHITENESS` of its greatest, by more than 2 standard errors of the two."""
    top, least = float(np.max(weight)), float(np.min(weight))
    if top <= 0 or least >= MIN_LOBE_WHITENESS * top:
        return False
    if error is None or not np.all(np.isfinite(error)):
        return True
    spread = math.hypot(float(error[np.argmax(weight)]), float(error[np.argmin(weight)]))
    return MIN_LOBE_WHITENESS * top - least > SIGNIFICANCE * spread


def _suffix_of(name: str) -> str | None:
    """The lobe suffix of a roughness's name (`"_2"` for `sigma_2`, `""` for `sigma`); None
    for any other name (a diffuse term's shape)."""
    return next((s for p in ROUGHNESS if (s := _suffix(name, p)) is not None), None)


def _roughness_name(values: dict, suffix: str) -> str | None:
    for prefix in ROUGHNESS:
        if prefix + suffix in values:
            return prefix + suffix
    return None


def _absent_lobes(
    values: dict, stderrs: dict, lobe_gain: float | None
) -> tuple[list[Undetermined], set[str]]:
    out, absent = [], set()
    scale = max(1.0, float(np.nanmax(_array(values.get("rho_tilde", [1.0])))))
    for name, value in values.items():
        suffix = _suffix(name, LOBE_WEIGHT)
        if suffix is None:
            continue
        weight = np.maximum(_array(value), 0)
        error = _array(stderrs.get(name))
        if error is not None and np.all(np.isfinite(error) & (error > 0)):
            chi2 = float(np.sum((weight / error) ** 2))
            why = f"within its standard errors of 0 (chi-square {chi2:.3g} over the channels)"
            zero = chi2 <= CHI2_3_95
        else:
            why, zero = "at the nonnegativity bound", bool(np.all(weight <= 1e-6 * scale))
        small = lobe_gain is not None and lobe_gain < MIN_LOBE_GAIN
        coloured = _coloured(weight, error)
        if not (zero or small or coloured):
            continue
        if small and not zero:
            why = (
                f"not seen in the data: where it predicts at least one 8-bit level, the lobe "
                f"{rmse_change(lobe_gain)} against the model without it "
                f"(under {100 * MIN_LOBE_GAIN:g}% lower)"
            )
        elif coloured and not zero:
            why = (
                "coloured: a specular reflection has the light's colour, and this lobe's "
                f"least channel is under {MIN_LOBE_WHITENESS:g} of its greatest (it explains "
                "something else: the camera's response, a colour shift with the angle)"
            )
        rough = _roughness_name(values, suffix)
        absent.add(suffix)
        shown = ", ".join(f"{w:.3g}" for w in weight)
        out.append(
            Undetermined(
                name,
                Status.no_lobe,
                f"{name} = [{shown}] is {why}: no specular lobe is found"
                + (
                    f", and {rough} = {float(values[rough]):.4g} is not determined by the data"
                    if rough
                    else ""
                ),
            )
        )
    return out, absent


def _shape_at_bound(name: str, value: float, lo: float, hi: float) -> Undetermined | None:
    """Another searched parameter (a diffuse term's shape: `oren_nayar_roughness`) at either
    end of its search range."""
    edge = EDGE * (hi - lo)
    if lo + edge < value < hi - edge:
        return None
    end = "top" if value >= hi - edge else "bottom"
    return Undetermined(
        name,
        Status.at_bound,
        f"{name} = {value:.4g} is at the {end} of its search range ({lo:.4g}, {hi:.4g}): the "
        "data ask for "
        + (
            "more than the term describes (for a diffuse roughness: shading flatter than its "
            "flattest, e.g. light scattered under the surface)"
            if end == "top"
            else "the term's limit (for a diffuse roughness, 0 is Lambert's cosine law)"
        )
        + "; it is no measurement of the parameter, and its standard error, computed at the "
        "bound, means nothing",
    )


def _at_bounds(values: dict, ranges: dict, absent: set[str]) -> list[Undetermined]:
    out = []
    for name, value in values.items():
        suffix = _suffix_of(name)
        if suffix is None and name in ranges and np.ndim(value) == 0:
            found = _shape_at_bound(name, float(value), *ranges[name])
            out += [] if found is None else [found]
            continue
        if suffix is None or suffix in absent:
            continue
        lo, hi = ranges.get(name, PAPER_ROUGHNESS_RANGE)
        v, edge = float(value), EDGE * (hi - lo)
        if v >= min(hi - edge, TREND):
            where = (
                f"at the top of its search range ({lo:g}, {hi:g}]"
                if v >= hi - edge
                else ("near or above 1")
            )
            out.append(
                Undetermined(
                    name,
                    Status.at_bound,
                    f"{name} = {v:.4g} is {where}: a lobe this broad explains an angular "
                    "trend (a falloff, vignetting, the camera's response, a non-Lambertian "
                    "diffuse term), not a highlight; it is no measurement of roughness",
                )
            )
        elif v <= lo + edge:
            out.append(
                Undetermined(
                    name,
                    Status.at_bound,
                    f"{name} = {v:.4g} is at the bottom of its search range ({lo:g}, {hi:g}]: "
                    "a lobe sharper than the data resolve (look at the highlights' size and "
                    "the normals there); it is no measurement of roughness",
                )
            )
    return out


def roughness_at_an_end(values: dict, ranges: dict) -> list[Undetermined]:
    """The roughnesses of `values` at an end of their search range (`ranges` by name; the
    paper's (0, 1] where missing), whatever their lobes' weights: `at_bound` each."""
    roughnesses = {n: v for n, v in values.items() if _suffix_of(n) is not None}
    return _at_bounds(roughnesses, ranges, set())


def halves_apart(values: dict, halves: dict, flagged: set[str]) -> list[Undetermined]:
    out = []
    for name, parts in halves.items():
        if name in flagged or name not in values or len(parts) != 2:
            continue
        a, b = parts
        if not (math.isfinite(a) and math.isfinite(b)):
            continue  # a half without data says nothing either way
        spread = abs(a - b) / max(abs(a + b) / 2, 1e-12)
        if spread <= HALVES_AGREE:
            continue
        what = "parameter" if _suffix_of(name) is None else "lobe"
        out.append(
            Undetermined(
                name,
                Status.unstable,
                f"{name} = {float(values[name]):.4g} on all frames, but {a:.4g} on the even "
                f"frames and {b:.4g} on the odd ({spread:.0%} apart, over "
                f"{HALVES_AGREE:.0%}): the {what} is not stable across frame subsets, whatever "
                "its standard error",
            )
        )
    return out


def _imprecise(values: dict, stderrs: dict, flagged: set[str]) -> list[Undetermined]:
    out = []
    for name, error in stderrs.items():
        if name in flagged or name not in values or _suffix_of(name) is None:
            continue
        value, error = _array(values[name]), _array(error)
        if error is None or not np.all(np.isfinite(error)) or value.shape != error.shape:
            continue
        relative = float(np.max(error / np.maximum(np.abs(value), 1e-300)))
        if relative <= MAX_RELATIVE_ERROR:
            continue
        v, e = float(np.max(value)), float(np.max(error))
        out.append(
            Undetermined(
                name,
                Status.imprecise,
                f"{name} = {v:.4g} +- {e:.2g}: its standard error is {relative:.0%} of it "
                f"(over {MAX_RELATIVE_ERROR:.0%}); the data leave it anywhere from "
                f"{max(v - 2 * e, 0):.3g} to {v + 2 * e:.3g} (2 standard errors): no "
                "measurement of it",
            )
        )
    return out


def _without_errors(values: dict, stderrs: dict, flagged: set[str]) -> list[Undetermined]:
    out = []
    for name, error in stderrs.items():
        if name in flagged or name not in values:
            continue
        errors = _array(error)
        if errors is not None and np.all(np.isfinite(errors)):
            continue
        out.append(
            Undetermined(
                name,
                Status.no_standard_error,
                f"the standard error of {name.removesuffix('_mm')} could not be computed: "
                "the data do not "
                "constrain it (a rank-deficient Jacobian at the solution)",
            )
        )
    return out


def undetermined(
    values: dict,
    stderrs: dict,
    ranges: dict[str, tuple[float, float]] | None = None,
    lobe_gain: float | None = None,
    halves: dict[str, tuple[float, float]] | None = None,
) -> list[Undetermined]:
    """The parameters the data do not determine (see the module doc).

    `values`: named parameters (`named_parameters(model)`); `stderrs`: their standard errors
    by the same names (None or non-finite where they could not be computed; a name missing
    is not checked); `ranges`: each roughness's search range (default: the paper's (0, 1]);
    `lobe_gain`: the relative RMSE decrease the specular lobes bring against the same fit
    without them (None: not known); `halves`: {roughness name: (value on the even frames,
    on the odd)}."""
    lobes, absent = _absent_lobes(values, stderrs, lobe_gain)
    bounds = _at_bounds(values, ranges or {}, absent)
    flagged = {u.parameter for u in lobes + bounds}
    # A roughness whose lobe is absent: its standard error is not the news.
    flagged |= {_roughness_name(values, s) for s in absent}
    unstable = halves_apart(values, halves or {}, flagged)
    flagged |= {u.parameter for u in unstable}
    imprecise = _imprecise(values, stderrs, flagged)
    flagged |= {u.parameter for u in imprecise}
    return lobes + bounds + unstable + imprecise + _without_errors(values, stderrs, flagged)


def flag(
    estimate,
    stderrs: dict,
    ranges: dict[str, tuple[float, float]] | None = None,
    values: dict | None = None,
    lobe_gain: float | None = None,
    halves: dict[str, tuple[float, float]] | None = None,
):
    """`estimate` (an `Estimate`) with what its data do not determine: a warning each, the
    list in `details["undetermined"]` and, where the solve succeeded, the status of the
    first by `PRIORITY`. `values`: the parameters by name (default: the model's
    `named_parameters`); `lobe_gain`, `halves` as in `undetermined`. Returns the same
    estimate."""
    from ._json import named_parameters

    values = named_parameters(estimate.model) if values is None else values
    found = undetermined(values, stderrs, ranges, lobe_gain, halves)
    estimate.details["undetermined"] = [u.to_json() for u in found]
    estimate.warnings[:] = [w for w in estimate.warnings if not w.startswith("undetermined: ")]
    estimate.warnings.extend(f"undetermined: {u.reason}" for u in found)
    if found and Status(estimate.status) == Status.successful:
        estimate.status = min((u.status for u in found), key=PRIORITY.index)
    return estimate


def add_undetermined(estimate, found: Undetermined):
    """`estimate` with one more thing its data do not determine (a check beyond `flag`'s):
    its warning, its entry in `details["undetermined"]` and, where the estimate was
    successful, its status."""
    estimate.details.setdefault("undetermined", []).append(found.to_json())
    estimate.warnings.append(f"undetermined: {found.reason}")
    if Status(estimate.status) == Status.successful:
        estimate.status = found.status
    return estimate


def flag_model(estimate, stderrs: dict | None = None, ranges=None, lobe_gain=None, halves=None):
    """`flag` for an estimate whose standard errors are in `details["stderr"]` by dotted
    field name (the LM fitters'), plus `stderrs` by paper name; `lobe_gain` and `halves` as
    in `undetermined`. A per-frame parameter (`PER_FRAME`: a frame's exposure) is a nuisance,
    as a point's albedo is, and flags nothing: a held-out frame's is fitted on that frame
    when it is judged, and has no standard error from the calibration frames."""
    from ._json import paper_names
    from .fitting._parameters import per_frame_names

    names = paper_names(estimate.model)
    nuisance = set(per_frame_names(estimate.model))
    stderr = estimate.details.get("stderr", {})
    held = effects_at_domain_end(estimate.model, stderr)
    if held:
        estimate.details["at_domain_end"] = {names.get(k, k): v for k, v in held.items()}
    nuisance |= set(held)
    by_name = {names[k]: v for k, v in stderr.items() if k in names and k not in nuisance}
    ranges = _diffuse_shape_ranges(estimate.model, names) | (ranges or {})
    return flag(estimate, by_name | (stderrs or {}), ranges, lobe_gain=lobe_gain, halves=halves)


def effects_at_domain_end(model, stderr: dict) -> dict[str, str]:
    """The image effects' parameters (dotted names) whose standard errors could not be
    computed because the effect sits at its limit, with why: one at an end of its domain
    (within `EDGE` of its width; a knee's slope at 1, a channel it does not compress) is
    held there by the domain, and the same effect's other parameters without an error are
    left open by it (a knee's level, where no channel is compressed). A flat direction of
    the fit that says nothing about the rest: it flags nothing."""
    from .fitting._parameters import free_parameters

    held, open_, reasons = set(), {}, {}
    for p in free_parameters(model):
        if not p.name.startswith("effects[") or p.name not in stderr:
            continue
        error = _array(stderr[p.name])
        error = np.array([np.nan]) if error is None else error  # None: not computed
        if np.all(np.isfinite(error)):
            continue
        effect = p.name.split(".")[0]
        open_.setdefault(effect, []).append(p.name)
        value = np.asarray(p.get(model), float).reshape(-1)
        lo, hi = p.domain
        ends = [end for end in (lo, hi) if math.isfinite(end)]
        if not ends or value.shape != error.shape:
            continue
        edge = EDGE * ((hi - lo) if len(ends) == 2 else max(abs(ends[0]), 1.0))
        lost = value[~np.isfinite(error)]
        if all(min(abs(v - end) for end in ends) <= edge for v in lost):
            held.add(effect)
            reasons[p.name] = (
                f"{', '.join(f'{v:.4g}' for v in lost)} at the end of its domain ({lo:g}, "
                f"{hi:g}): held there, no standard error (the effect at its limit)"
            )
    out = {}
    for effect in held:
        for name in open_[effect]:
            out[name] = reasons.get(
                name, "no standard error where the same effect is at its limit (above)"
            )
    return out


def _diffuse_shape_ranges(model, names: dict) -> dict[str, tuple[float, float]]:
    """The domains of a diffuse lobe's shape parameters (`oren_nayar_roughness`), by paper
    name: an LM fit searches them there, and one at an end is at its bound."""
    from .fitting._parameters import free_parameters
    from .lobes import Lambertian

    lobes = model.brdf.lobes
    diffuse = [f"brdf.lobes[{i}]." for i, lobe in enumerate(lobes) if isinstance(lobe, Lambertian)]
    return {
        names[p.name]: p.domain
        for p in free_parameters(model)
        if p.name in names
        and p.name.startswith(tuple(diffuse))
        and not p.name.endswith(".weight")
        and all(np.isfinite(p.domain))
    }
