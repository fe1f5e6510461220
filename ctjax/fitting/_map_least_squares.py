"""The general fitter with an albedo map: any BRDF and light fitted by Levenberg-Marquardt
to tracked surface points, every point's albedo and the global linear weights eliminated in
closed form (variable projection) rather than added to LM as 10^5 parameters.

LM sees only the nonlinear parameters (sigma, the light's offset, its falloff...): for each
value it asks for, the residuals are those of the best albedos and global weights
(`ctjax.estimation.projected_residuals`), and autodiff differentiates through that closed
form (Golub and Pereyra's exact variable-projection Jacobian).
"""

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._buckets import bucket
from .._convert import cast_floating, on_device
from .._errors import ParameterError
from .._paired import SampleErrors
from .._programs import persistent_jit
from .._result import Estimate
from .._status import Status
from .._tracks import Tracks, views_first
from .._vector import Vec3
from ..effects import AbstractImageEffect
from ..effects._effect import Site, apply_effects, undo_effects
from ..estimation._variable_projection import (
    albedo_from_other_views,
    over_views_at_once,
    projected_residuals,
)
from ..lobes import Lambertian
from ..solvers import JacobianBlocks, Solver, least_squares
from ..solvers._gram import gram
from ._fit import LEVENBERG_MARQUARDT, distinct, named_errors
from ._parameters import as_vector, constrained, free_parameters, strongly_typed, unconstrained

# The commands' map fits run their LM in float32 (`fit_model_map(..., dtype=MAP_LM_DTYPE)`):
# 8-bit measurements and residuals in levels, 3-4x faster a step; standard errors, held-out
# figures and the reported models stay in float64. The second sinus video's turbinate (24
# frames, 640 px): `calibrate-light` 80 s against 136-192 s, every figure within 1e-4;
# `diagnose --albedo map` 152 s against 189 s, the same verdict, every candidate's cost
# within 2e-4 but one that float32 took 0.8% lower (docs/measurements.md).
MAP_LM_DTYPE = np.float32


class TrackSamples(eqx.Module):
    """Tracks as the general fitter sees them, views first and points last
    (`ctjax._tracks.views_first`): every observation's four corners flattened (4 M P:
    camera-frame point, normal, pixel), their bilinear weights (4, M, P), the measured RGB
    (3, M, P), each observation's least-squares weight (M, P) and where it was recorded
    (`site`: its sub-pixel position and frame, (M, P) each; -1 where unobserved); `eye`
    (4 M P) where some views are from a camera away from the light's lens (`Tracks`)."""

    point: Vec3
    normal: Vec3
    pixel: tuple
    corner_weight: jax.Array
    values: jax.Array
    weight: jax.Array
    site: Site
    eye: Vec3 | None = None

    @classmethod
    def of(cls, tracks: Tracks, dtype=None, *, pad: bool = True) -> "TrackSamples":
        """`tracks` as arrays; with `pad`, the points padded with unobserved ones to the
        next bucket size (`ctjax._buckets`: 2^k or 3 2^(k-1), at least 1024), so that
        captures of similar size share the fitters' compilations. Not to the next power of
        two, as until 2026-12-06: the commands' 12000 points were 16384 rows, a third of
        every map fit's work on padding (now 12288)."""
        dtype = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
        if pad:
            tracks = tracks.padded(max(1024, bucket(len(tracks))))
        as_jax = lambda a: on_device(views_first(a), dtype)  # noqa: E731
        # Split on the host: an eager slice of a JAX array compiles a program per shape.
        pixel = views_first(tracks.corner_pixel)
        at = views_first(np.einsum("pmc,pmcd->pmd", tracks.corner_weight, tracks.corner_pixel))
        return cls(
            Vec3.from_array(as_jax(tracks.corner_point)),
            Vec3.from_array(as_jax(tracks.corner_normal)),
            (on_device(pixel[:, 0], dtype), on_device(pixel[:, 1], dtype)),
            as_jax(tracks.corner_weight),
            as_jax(tracks.values),
            as_jax(tracks.weight),
            Site(
                (on_device(at[0], dtype), on_device(at[1], dtype)),
                on_device(views_first(tracks.frame), np.int32),
            ),
            None if tracks.corner_eye is None else Vec3.from_array(as_jax(tracks.corner_eye)),
        )

    @property
    def channels(self) -> int:
        return self.values.shape[0]


def diffuse_lobe(model) -> int:
    """Index of the lobe whose weight is per point: the (first) Lambertian one."""
    for index, lobe in enumerate(model.brdf.lobes):
        if isinstance(lobe, Lambertian):
            return index
    raise ParameterError("an albedo map needs a Lambertian lobe in the model's BRDF")


def _columns(model, samples: TrackSamples):
    """Each lobe's value for unit weight at every observation (M, P): at the corners,
    bilinearly combined like the image."""
    corners = samples.corner_weight
    where = (samples.point, samples.normal, samples.pixel)
    where += () if samples.eye is None else (samples.eye,)
    columns = jax.vmap(model.columns)(*where)
    return tuple(
        jnp.sum(columns[:, k].reshape(corners.shape) * corners, axis=0)
        for k in range(columns.shape[-1])
    )


def _weights_frozen(name: str) -> bool:
    return name.startswith("brdf.lobes[") and name.endswith("].weight")


# The largest slope of the image effects an observation's weight follows (a camera gamma
# is infinitely steep at 0).
_MAX_SLOPE = 1e3
# ...and at least this (a channel an effect flattens entirely counts for nothing).
_MIN_SLOPE = 1e-6
# Measurements are read as at least a quarter of an 8-bit level where effects are undone.
_DARKEST = 0.25 / 255


def _linear(model, samples: TrackSamples, harmonic: bool = False):
    """The measured values with the model's image effects undone (their `inverse`), where
    the lobes' sum is linear in the albedo again, and the observation weights times the
    effects' squared slope there (mean over channels), so that residuals read in the
    image's units to first order. Without effects: the values and weights as they are.
    `harmonic`: the harmonic mean over channels instead, so that a view's noise in
    radiance, summed over its channels (sigma^2 / slope_c^2 each), counts as its three
    channels' as recorded: for judging a model on the undone values (`in_radiance`). The
    arithmetic mean lets a channel the camera compressed (a knee's red at slope 0.21) count
    15 times its share at the bright views, where undoing divides its noise by the slope;
    the fits keep it (their residuals are the image's; on a synthetic hidden knee the
    harmonic mean in the albedos' elimination took red's F_tilde from 0.277 to 0.258, truth
    0.3)."""
    effects = tuple(getattr(model, "effects", ()))
    if not effects:
        return samples.values, samples.weight

    # Unobserved slots (0) and black pixels at a harmless value: a gamma's slope is
    # infinite at 0, and its derivative in gamma takes log(0).
    observed = samples.weight > 0
    values = jnp.where(observed, jnp.maximum(samples.values, _DARKEST), 0.5)
    flat = values.reshape(samples.channels, -1)
    sites = _flat_sites(samples)
    linear = jax.vmap(lambda x, site: undo_effects(effects, x, site), (1, 0), 1)(flat, sites)

    def slope_at(x, site):
        apply = lambda rgb: apply_effects(effects, rgb, site)  # noqa: E731
        return jax.jvp(apply, (x,), (jnp.ones_like(x),))[1]

    slope = jax.vmap(slope_at, (1, 0), 1)(linear, sites)
    slope = jnp.clip(jnp.abs(slope), _MIN_SLOPE, _MAX_SLOPE)
    if harmonic:  # the view's noise in radiance summed over channels as recorded (above)
        scale = slope.shape[0] / jnp.sum(1 / (slope * slope), axis=0)
    else:
        scale = jnp.mean(slope * slope, axis=0)
    scale = scale.reshape(samples.weight.shape)
    return linear.reshape(samples.values.shape), samples.weight * scale


def in_radiance(model, samples: TrackSamples) -> TrackSamples:
    """`samples` with `model`'s image effects undone on every measured value and each
    observation's weight times the harmonic mean of the effects' squared slopes there over
    the channels (`_linear`): what an estimator of a model without image effects can take, its
    residuals in the image's levels to first order. Without effects: `samples`."""
    if not tuple(getattr(model, "effects", ())):
        return samples
    values, weight = _in_radiance(strongly_typed(model), samples)
    return eqx.tree_at(lambda s: (s.values, s.weight), samples, (values, weight))


@persistent_jit
def _in_radiance(model, samples):
    return _linear(model, samples, harmonic=True)


def _flat_sites(samples: TrackSamples) -> Site:
    """Where each observation was recorded, flattened (M P,) like the values' columns."""
    (u, v), frame = samples.site
    return Site((u.reshape(-1), v.reshape(-1)), frame.reshape(-1))


def _apply_effects(model, linear, samples: TrackSamples):
    """The model's image effects applied to linear RGB (3, M, P), each observation's
    where it was recorded."""
    effects = tuple(getattr(model, "effects", ()))
    flat = linear.reshape(linear.shape[0], -1)
    apply = lambda rgb, site: apply_effects(effects, rgb, site)  # noqa: E731
    return jax.vmap(apply, (1, 0), 1)(flat, _flat_sites(samples)).reshape(linear.shape)


def _root(weight):
    positive = weight > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, weight, 1)), 0)


def _projected(model, samples: TrackSamples, per_point: int, over=over_views_at_once):
    """`projected_residuals` of `model` on `samples`. With image effects the albedos and
    global weights are eliminated where the model is linear (the measurements with the
    effects undone, `_linear`), and the residuals are the image's: the effects applied to
    that prediction, minus the measurements, weighted as observed. `over`: the sums over
    views, as one reduction (one model and its forward-mode Jacobian: 2-5x faster than
    the branch and bound's adds, `over_views_at_once`)."""
    values, weight = _linear(model, samples)
    columns = _columns(model, samples)
    albedo, weights, residual = projected_residuals(columns, values, weight, per_point, over)
    if not tuple(getattr(model, "effects", ())):
        return albedo, weights, residual
    linear = sum(
        c * (albedo.T[:, None, :] if k == per_point else weights[k][:, None, None])
        for k, c in enumerate(columns)
    )
    image = _apply_effects(model, linear, samples)
    return albedo, weights, (samples.values - image) * _root(samples.weight)


@persistent_jit
def projected_cost(model, samples: TrackSamples, per_point: int):
    """The weighted sum of squared residuals of `model`'s nonlinear parameters with every
    albedo and the global weights eliminated (what `fit_model_map` minimises)."""
    _, _, residual = _projected(model, samples, per_point)
    return jnp.sum(residual * residual)


# A lobe "shows" at an observation where it predicts at least this (linear units: one
# 8-bit level), in some channel.
LOBE_SHOWS = 1 / 255


@persistent_jit
def _where_lobes_show(model, plain, samples: TrackSamples, per_point: int, plain_point: int):
    """Sums of squared (weighted) residuals of `model` and of `plain` (the same light,
    without the lobes), each with every point's albedo eliminated, over the observations
    where `model`'s lobes other than the per-point one predict at least `LOBE_SHOWS`; and
    their number."""
    columns = _columns(model, samples)
    weights = model.brdf.weights
    lobes = sum(
        c[None] * weights[k][:, None, None] for k, c in enumerate(columns) if k != per_point
    )
    shows = (jnp.max(lobes, axis=0) >= LOBE_SHOWS) & (samples.weight > 0)
    ssr = lambda r: jnp.sum(jnp.where(shows[None], r * r, 0))  # noqa: E731
    return (
        ssr(_projected(model, samples, per_point)[2]),
        ssr(_projected(plain, samples, plain_point)[2]),
        jnp.sum(shows),
    )


def lobe_gain_where_it_shows(model, plain, tracks: "Tracks | TrackSamples") -> tuple[float, int]:
    """What `model`'s specular lobes bring where they show: 1 - RMSE / RMSE of `plain` (the
    same light and effects, a Lambertian BRDF: fitted on the same tracks) over the
    observations where the lobes predict at least one 8-bit level, every point's albedo
    eliminated; and how many observations that is (0: the lobes show nowhere, gain 0).

    Over every observation a lobe that the data determine well can bring under 0.5%: a
    laparoscope's highlights are few and mostly clipped (measured: a light 7 mm off the
    lens with inverse-square and spot falloff, F_tilde 0.3 and sigma 0.2 recovered within
    7% and 4%, lowered the RMSE of every observation by 0.26%)."""
    samples = tracks if isinstance(tracks, TrackSamples) else TrackSamples.of(tracks)
    fit_ssr, plain_ssr, count = _where_lobes_show(
        strongly_typed(model),
        strongly_typed(plain),
        samples,
        diffuse_lobe(model),
        diffuse_lobe(plain),
    )
    count, fit_ssr, plain_ssr = int(count), float(fit_ssr), float(plain_ssr)
    if count == 0 or not plain_ssr > 0 or not np.isfinite(fit_ssr):
        return 0.0, count
    return 1 - math.sqrt(fit_ssr / plain_ssr), count


@persistent_jit
def _predicted_views(model, samples: TrackSamples, judged, per_point: int):
    """The residuals (C, M, P; 0 where not judged) and weights (M, P) of the `judged`
    observations, each predicted by `model` (all its parameters fixed) with its point's albedo
    fitted to the point's OTHER views (per channel, clamped at 0), where those hold enough
    of the information (`OTHER_VIEWS_SHARE`)."""
    columns = _columns(model, samples)
    weights = model.brdf.weights
    values, w = _linear(model, samples)
    a = columns[per_point]
    rest = sum(c * weights[k][:, None, None] for k, c in enumerate(columns) if k != per_point)
    target = values - rest  # (C, M, P)
    albedo, ok = albedo_from_other_views(a, target, w, judged)
    residual = target - a * albedo
    w = samples.weight
    if tuple(getattr(model, "effects", ())):  # the image's residual (see `_projected`)
        residual = samples.values - _apply_effects(model, rest + a * albedo, samples)
    residual = jnp.where(ok, residual, 0)
    return residual, jnp.where(ok, w, 0)


@persistent_jit
def _predicted_ssr(model, samples: TrackSamples, judged, per_point: int):
    """Each point's weighted sum of squared residuals and sum of weights over its channels
    and judged views (P,) each (`_predicted_views`)."""
    residual, w = _predicted_views(model, samples, judged, per_point)
    return jnp.sum(w * residual * residual, axis=(0, 1)), jnp.sum(w, axis=0) * samples.channels


def heldout_map_residuals(
    model, samples: TrackSamples, judged=None, per_point: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Each `judged` observation's residual as `heldout_map_rmse` counts it: (C, M, P)
    measured - predicted in 8-bit levels and (M, P) its weight (0 where not judged)."""
    per_point = diffuse_lobe(model) if per_point is None else per_point
    judged = samples.weight > 0 if judged is None else jnp.asarray(judged)
    residual, w = _predicted_views(strongly_typed(model), samples, judged, per_point)
    return 255 * np.asarray(residual), np.asarray(w)


def heldout_map_rmse(
    model, samples: TrackSamples, judged=None, per_point: int | None = None
) -> float:
    """RMSE (8-bit levels) of a fitted `model` predicting views it was not fitted on: every
    `judged` observation (M, P as `samples.weight`; all observed by default) of a
    tracked point predicted with all of the model's parameters fixed and the point's
    albedo (a nuisance) fitted to its other views, never to the view judged, where they
    hold at least `OTHER_VIEWS_SHARE` of the view's own information (the others are not
    judged; the total weight counts the judged ones only). A model that
    is right gives about the noise (a little more: the albedo is itself estimated; less
    where bilinear sampling averages the noise). Weighted as in the fit."""
    return heldout_map_errors(model, samples, judged, per_point).rmse


def heldout_map_errors(
    model, samples: TrackSamples, judged=None, per_point: int | None = None
) -> SampleErrors:
    """Each tracked point's error as `heldout_map_rmse` counts it: its weighted squared
    residual over its judged views and channels (8-bit levels^2), their weight, and the
    frame and pixel where it is first judged (for comparing two models point by point,
    `ctjax._paired`)."""
    per_point = diffuse_lobe(model) if per_point is None else per_point
    judged = samples.weight > 0 if judged is None else jnp.asarray(judged)
    squared, total = _predicted_ssr(strongly_typed(model), samples, judged, per_point)
    first = np.argmax(np.asarray(judged), axis=0)  # (P,): each point's first judged view
    points = np.arange(first.size)
    at = lambda a: np.asarray(a)[first, points]  # noqa: E731
    u, v = samples.site.pixel
    return SampleErrors(
        255**2 * np.asarray(squared, float),
        np.asarray(total, float),
        at(samples.site.frame),
        at(v),
        at(u),
    )


def _blocks(parameters, start):
    """The unknowns as DenseLM's `JacobianBlocks` where the model has image effects: the
    shading's (light, BRDF) and the effects' (applied to the shaded image: their columns
    need no pass through the shading); and the map from that start's shape back to the
    parameters' list. Without effects: `start` as it is."""
    of_effects = [p.name.startswith("effects") for p in parameters]
    if all(of_effects) or not any(of_effects):
        return start, lambda y: y
    shading = [i for i, e in enumerate(of_effects) if not e]
    effects = [i for i, e in enumerate(of_effects) if e]

    def as_list(y):
        merged = [None] * len(start)
        for indices, block in zip((shading, effects), y, strict=True):
            for i, value in zip(indices, block, strict=True):
                merged[i] = value
        return merged

    return JacobianBlocks(
        (tuple(start[i] for i in shading), tuple(start[i] for i in effects))
    ), as_list


@persistent_jit
def _least_squares(model, samples, names, per_point, solver, max_steps, held):
    """LM over the parameters not frozen by `names`; those flagged in `held` (a bool per
    parameter, an array: one compiled program whatever it holds) stay at their start."""
    freeze = lambda name: name in names or _weights_frozen(name)  # noqa: E731
    parameters = free_parameters(model, freeze)
    if not parameters:  # all linear (e.g. Lambertian alone): the projection is the fit
        albedo, weights, residual = _projected(model, samples, per_point)
        done = jnp.asarray(Status.successful.value)
        return model, albedo, weights, jnp.sum(residual * residual), done, jnp.asarray(0)
    start = unconstrained(model, parameters)
    y0, as_list = _blocks(parameters, start)

    def kept(u):  # a held parameter's step has a zero Jacobian column: it never moves
        return [jnp.where(held[i], s, v) for i, (s, v) in enumerate(zip(start, u, strict=True))]

    def residuals(y):
        """In 8-bit levels (so are the tolerances); the eliminated albedos and weights and
        the sum of squares as aux."""
        albedo, weights, residual = _projected(
            constrained(model, parameters, kept(as_list(y))), samples, per_point
        )
        return 255 * residual.reshape(-1), (albedo, weights, jnp.sum(residual * residual))

    value, status, steps, (albedo, weights, cost) = least_squares(
        residuals, solver, y0, max_steps, has_aux=True
    )
    fitted = constrained(model, parameters, kept(as_list(value)))
    return fitted, albedo, weights, cost, status, steps


# Observations (views x tracked points, `TrackSamples.weight.size`) from which `hold` freezes
# instead: a held parameter still costs its Jacobian column in every LM step. The near
# light's refits hold the light (most of the Jacobian's columns): `calibrate_near_light`
# on the second sinus video (24 frames at 640 px, samples 13 x 12288) 130-139 -> 85 s warm
# (its cold run 107 s, compiling the frozen programs included), the same fit to 1e-13. The
# tests' captures (5k-40k) stay under it: one compiled program for both, as before.
FREEZE_HELD_FROM = 65_536


def fit_model_map(
    starts: eqx.Module | Sequence[eqx.Module],
    tracks: Tracks | TrackSamples,
    *,
    freeze: Sequence[str] = (),
    hold: Sequence[str] = (),
    solver: Solver = LEVENBERG_MARQUARDT,
    max_steps: int = 100,
    refine: int | None = None,
    standard_errors: bool = True,
    dtype=None,
) -> Estimate:
    """Fit `ShadingModel`s (one or several starts of the same structure) to tracked surface
    points with one albedo per point (the diffuse lobe's weight) and the other lobes' weights
    shared, both eliminated in closed form; LM runs over the remaining parameters (`freeze`
    holds more fixed; `hold` too, in the same compiled program as without it: a model
    with and without a parameter held costs one compilation, not two; from
    `FREEZE_HELD_FROM` observations on, frozen: there a step costs more than a
    compilation). Image effects (a camera gamma, an ambient term) are undone on the
    measurements
    (`AbstractImageEffect.inverse`: the albedo is linear again there), each observation
    weighted by the effects' squared slope; an effect without an inverse is refused.

    Returns an `Estimate` of the best start: the model with its global weights and, in the
    diffuse lobe, the median albedo of the points seen twice or more; `rmse["calibration"]`
    the weighted RMSE (8-bit levels) over the observations; `arrays["track_albedo"]` every
    point's albedo (P, 3; given `TrackSamples`, padded rows included);
    `details["albedo"] = "map"`, `details["stderr"]` the standard error of every fitted
    parameter by name (physical units, from the Jacobian of the
    projected residuals at the solution: the albedos' uncertainty is accounted for, as the
    global block of the joint covariance is). With `refine`, LM runs from the `refine`
    starts of lowest projected cost only (each costs one closed-form projection).
    `standard_errors=False` skips them (one compilation less per model structure).
    `dtype`: the LM's precision where it is not the samples' (the commands':
    `MAP_LM_DTYPE`, float32); the result in the samples' and the starts' own.
    """
    starts = [starts] if isinstance(starts, eqx.Module) else list(starts)
    for start in starts:
        for effect in getattr(start, "effects", ()):
            here = effect.at(Site((jnp.zeros(()), jnp.zeros(())), jnp.zeros((), jnp.int32)))
            if type(here).inverse is AbstractImageEffect.inverse:
                raise ParameterError(
                    f"fit_model_map needs image effects it can undo: {type(effect).__name__} "
                    "has no inverse (an effect after the lobes makes the albedo nonlinear; "
                    "the map fit undoes it on the measurements)"
                )
    points = None if isinstance(tracks, TrackSamples) else len(tracks)
    samples = tracks if isinstance(tracks, TrackSamples) else TrackSamples.of(tracks)
    views = np.sum(np.asarray(samples.weight) > 0, axis=0)
    per_point = diffuse_lobe(starts[0])
    starts = [strongly_typed(start) for start in starts]
    # The result is reported in the samples' dtype and in its start's own dtypes: by start,
    # for starts may differ in structure (the Fresnel factor's "half" and "normal").
    fitted_in, given = samples, starts
    if dtype is not None:
        samples = cast_floating(samples, dtype)
        starts = [cast_floating(start, dtype) for start in starts]
    own = {id(start): like for start, like in zip(starts, given, strict=True)}
    if refine is not None and len(starts) > refine:
        costs = [float(projected_cost(m, samples, per_point)) for m in starts]
        starts = [starts[i] for i in np.argsort(costs)[:refine]]
    best = None
    free = lambda n: n in tuple(freeze) or _weights_frozen(n)  # noqa: E731
    held = np.array([p.name in hold for p in free_parameters(starts[0], free)], bool)
    if held.size and (held.all() or samples.weight.size >= FREEZE_HELD_FROM):
        # Nothing left to fit (the projection is the fit), or samples large enough that
        # a held parameter's Jacobian column costs more than compiling a second program.
        freeze = (*freeze, *hold)
        free = lambda n: n in freeze or _weights_frozen(n)  # noqa: E731
        held = np.zeros(len(free_parameters(starts[0], free)), bool)
    for start in distinct(starts):
        fitted, albedo, weights, cost, result, steps = _least_squares(
            start, samples, tuple(freeze), per_point, solver, max_steps, held
        )
        cost = float(cost)
        if np.isfinite(cost) and (best is None or cost < best[3]):
            best = (fitted, albedo, weights, cost, result, int(steps), own[id(start)])
    if best is None:
        return Estimate(given[0], {"calibration": math.inf}, Status.failed, cost=math.inf)
    fitted, albedo, weights, cost, result, steps, like = best
    fitted = jax.tree_util.tree_map(
        lambda x, like: jnp.asarray(x, like.dtype) if isinstance(like, jax.Array) else x,
        fitted,
        like,
    )
    samples = fitted_in
    albedo = np.asarray(albedo, samples.values.dtype)
    weights = np.asarray(weights, samples.values.dtype).copy()
    seen = views > 1
    weights[per_point] = np.median(albedo[seen], axis=0) if seen.any() else 0.0
    brdf = fitted.brdf.with_weights(jnp.asarray(weights, fitted.brdf.weights.dtype))
    fitted = eqx.tree_at(lambda m: m.brdf, fitted, brdf)
    total_weight = float(jnp.sum(samples.weight)) * samples.channels
    rmse = 255 * math.sqrt(cost / max(total_weight, 1e-300))
    fixed = tuple(dict.fromkeys((*freeze, *hold)))  # once each: a compiled program's key
    frozen = lambda n: n in fixed or _weights_frozen(n)  # noqa: E731
    parameters = [p.name for p in free_parameters(fitted, frozen)]
    errors = _standard_errors(fitted, samples, fixed, per_point) if standard_errors else {}
    return Estimate(
        fitted,
        {"calibration": rmse},
        Status(int(result)),
        cost=cost,
        details={"steps": steps, "parameters": parameters, "albedo": "map", "stderr": errors},
        arrays={"track_albedo": albedo[:points]},
    )


@persistent_jit
def _covariance(model, samples, names, per_point):
    freeze = lambda name: name in names or _weights_frozen(name)  # noqa: E731
    parameters = free_parameters(model, freeze)
    if not parameters:
        return 0.0, jnp.zeros((0, 0))
    flat, rebuilt = as_vector(model, parameters)

    def residuals(theta):
        fitted = rebuilt(theta)
        _, _, residual = _projected(fitted, samples, per_point)
        return residual.reshape(-1)

    jacobian = jax.jacfwd(residuals)(flat)
    residual = residuals(flat)
    observed = jnp.sum(samples.weight > 0) * samples.channels
    points = jnp.sum(jnp.any(samples.weight > 0, axis=0)) * samples.channels
    globals_ = (len(model.brdf.lobes) - 1) * samples.channels
    dof = jnp.maximum(observed - points - globals_ - flat.shape[0], 1)
    return jnp.sum(residual * residual) / dof, gram(jacobian)


def _standard_errors(model, samples, names, per_point) -> dict[str, list | float]:
    """Standard error of every free nonlinear parameter (see `fit_model_map`); None where
    the data do not determine it (`named_errors`)."""
    freeze = lambda name: name in names or _weights_frozen(name)  # noqa: E731
    parameters = free_parameters(model, freeze)
    scale, information = _covariance(model, samples, names, per_point)
    return named_errors(model, parameters, float(scale), np.asarray(information, np.float64))


def map_standard_errors(model, tracks: "Tracks | TrackSamples", freeze: Sequence[str] = ()):
    """`fit_model_map`'s `details["stderr"]` for a fitted `model` (e.g. one fitted with
    `standard_errors=False`, when only the chosen one of several needs them)."""
    samples = tracks if isinstance(tracks, TrackSamples) else TrackSamples.of(tracks)
    return _standard_errors(strongly_typed(model), samples, tuple(freeze), diffuse_lobe(model))
