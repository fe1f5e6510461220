"""The general fitter: any model fitted to measurements by Levenberg-Marquardt (optimistix)
on autodiff Jacobians, linear weights initialised in closed form, parameters kept physical
by reparametrisation, several starts."""

import math
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._buckets import padded
from .._programs import persistent_jit
from .._result import Estimate
from .._status import Status
from .._typing import Array, Float, Scalar
from ..effects._effect import Site, undo_effects
from ..estimation._closed_form import nnls
from ..lobes import BRDF
from ..solvers import DenseLM, Solver, least_squares
from ..solvers._gram import gram
from ._parameters import (
    Parameter,
    as_vector,
    constrained,
    free_parameters,
    strongly_typed,
    unconstrained,
)

# Predict one sample's RGB from a model: e.g. `lambda model, s: model(s.point, s.normal,
# s.pixel)` for pixels of a capture, or a BRDF evaluated at (L, V) for measured BRDF data.
Predict = Callable[[eqx.Module, eqx.Module], Float[Array, "3"]]


def predictions(model, samples, predict: Predict) -> Float[Array, "N 3"]:
    """The model's RGB at every sample."""
    return jax.vmap(lambda s: predict(model, s))(samples)


def rmse_levels(model, samples, predict: Predict, scale: float = 255.0) -> float:
    """Root-mean-square error of `model` on `samples`, times `scale` (255: 8-bit levels
    for images in linear units; 1 for measured BRDF data in their own units)."""
    squared = squared_errors(model, samples, predict, scale)
    if squared.size == 0:
        return math.nan
    return math.sqrt(float(np.sum(squared)) / (squared.size * samples.values.shape[-1]))


def squared_errors(model, samples, predict: Predict, scale: float = 255.0) -> np.ndarray:
    """Each sample's squared residual summed over its channels, times `scale`^2 (N,): the
    terms of `rmse_levels`, for comparing two models sample by sample (`ctjax._paired`)."""
    # One signature however `scale` is passed (default, positional, int or float), and the
    # samples padded to a bucket size (`ctjax._buckets`): the compiled function is shared.
    count = len(samples.values)
    if count == 0:
        return np.zeros(0)
    samples, mask = padded(samples, count)
    return np.asarray(_squared_errors(model, samples, mask, predict, float(scale)))[:count]


def frame_gains_of_pixels(model, samples, predict: Predict) -> dict[int, float]:
    """Each frame's measured over predicted brightness under `model` on pixel `samples`
    (their `frame`), by frame index: the gain g minimising sum |measured - g predicted|^2
    over the frame's samples (NaN where it predicts nothing). With one albedo the model's
    own fit on these samples, so g follows each frame's brightness about the frames' mean
    (`ctjax._frame_consistency.frame_gains` predicts each view from the other frames)."""
    count = len(samples.values)
    if count == 0:
        return {}
    padded_samples, mask = padded(samples, count)
    across, power = (
        np.asarray(a, float)[:count]
        for a in _brightness_terms(model, padded_samples, mask, predict)
    )
    frame = np.asarray(samples.frame)
    out = {}
    for f in sorted({int(f) for f in np.unique(frame)}):
        total = float(np.sum(power[frame == f]))
        out[f] = float(np.sum(across[frame == f])) / total if total > 0 else math.nan
    return out


@persistent_jit
def _brightness_terms(model, samples, mask, predict: Predict):
    predicted = jnp.where(mask[:, None], predictions(model, samples, predict), 0)
    return jnp.sum(samples.values * predicted, -1), jnp.sum(predicted * predicted, -1)


def _masked_residuals(model, samples, mask, predict: Predict) -> Float[Array, "N 3"]:
    """Prediction minus measurement, 0 on the padding rows."""
    residual = predictions(model, samples, predict) - samples.values
    return jnp.where(mask[:, None], residual, 0)


@persistent_jit
def _squared_errors(model, samples, mask, predict: Predict, scale: float) -> Float[Array, " N"]:
    residual = _masked_residuals(model, samples, mask, predict)
    return scale * scale * jnp.sum(residual * residual, axis=-1)


def _rmse_levels(model, samples, mask, predict: Predict, scale: float) -> Scalar:
    residual = _masked_residuals(model, samples, mask, predict)
    count = jnp.sum(mask) * samples.values.shape[-1]
    return scale * jnp.sqrt(jnp.sum(residual * residual) / count)


def _sites(samples) -> Site:
    """Where each sample was recorded (N,): its pixel and frame, or pixel (0, 0) of frame 0
    for samples that are not pixels (measured BRDF data)."""
    if hasattr(samples, "frame") and hasattr(samples, "pixel"):
        return Site(samples.pixel, samples.frame)
    zero = jnp.zeros(samples.values.shape[0])
    return Site((zero, zero), jnp.zeros(samples.values.shape[0], int))


# Weights start at least this fraction of the largest: a weight that starts at exactly the
# bound of its reparametrisation has no gradient and would stay there.
_WEIGHT_FLOOR = 1e-2


@persistent_jit
def initial_weights(model, samples, columns: Callable, mask=None) -> eqx.Module:
    """`model` with its lobe weights set by closed-form NNLS on the linear design
    `columns(model, sample) -> (K,)`, against the measurements with the model's image
    effects undone where they can be (`AbstractImageEffect.inverse`); rows where `mask` is
    False (padding) are left out."""
    design = jax.vmap(lambda s: columns(model, s))(samples)
    values = samples.values
    effects = tuple(getattr(model, "effects", ()))
    if effects:
        values = jax.vmap(lambda v, site: undo_effects(effects, v, site))(values, _sites(samples))
    if values.shape[-1] < 3:  # monochrome data: the same weight in every channel
        values = jnp.broadcast_to(values[:, :1], (values.shape[0], 3))
    if mask is not None:
        design = jnp.where(mask[:, None], design, 0)
        values = jnp.where(mask[:, None], values, 0)
    weights, _ = nnls(design, values)
    weights = jnp.maximum(weights, _WEIGHT_FLOOR * jnp.max(weights))
    if isinstance(model, BRDF):
        return model.with_weights(weights)
    return eqx.tree_at(lambda m: m.brdf, model, model.brdf.with_weights(weights))


@persistent_jit
def _started(model, samples, mask, predict, columns, scale):
    """A start with its weights from `columns` (when given) and its RMSE: one program."""
    if columns is not None:
        model = initial_weights(model, samples, columns, mask)
    return model, _rmse_levels(model, samples, mask, predict, scale)


@persistent_jit
def _least_squares(model, samples, mask, predict, names, solver, max_steps, scale):
    parameters = free_parameters(model, lambda name: name in names)

    def residuals(u):
        """In the user's units (8-bit levels for images): so are the tolerances; and the
        sum of squares in the data's, as aux."""
        residual = _masked_residuals(constrained(model, parameters, u), samples, mask, predict)
        return scale * residual.reshape(-1), jnp.sum(residual * residual)

    start = unconstrained(model, parameters)
    value, status, steps, cost = least_squares(residuals, solver, start, max_steps, has_aux=True)
    return constrained(model, parameters, value), cost, status, steps


def variances(scale: float, information: np.ndarray) -> np.ndarray:
    """The parameters' variances from their information matrix (times the residuals'
    variance `scale`): inf for a parameter the data leave alone (a zero column: sigma where
    every F_tilde is 0), and for every one where the rest are still rank-deficient."""
    size = len(information)
    diagonal = np.diagonal(information)
    determined = diagonal > 1e-12 * max(float(np.max(diagonal, initial=0.0)), 1e-300)
    variance = np.full(size, np.inf)
    block = information[np.ix_(determined, determined)]
    if determined.any() and np.linalg.matrix_rank(block) == determined.sum():
        variance[determined] = np.abs(np.diagonal(scale * np.linalg.pinv(block, hermitian=True)))
    return variance


def named_errors(model, parameters, scale: float, information: np.ndarray) -> dict:
    """The standard error of each of `parameters` (free parameters of `model`, in the
    order of `information`'s rows) by dotted name: a list for an array parameter, None
    where the data do not determine it (`variances`)."""
    variance = variances(scale, information)
    out, start = {}, 0
    for p in parameters:
        count = int(np.size(p.get(model)))
        value = [float(v) if np.isfinite(v) else None for v in np.sqrt(variance[start:][:count])]
        out[p.name] = value if np.ndim(p.get(model)) else value[0]
        start += count
    return out


@persistent_jit
def _information(model, samples, mask, predict, names):
    """The residuals' variance (their sum of squares over the degrees of freedom) and the
    Gauss-Newton information matrix J^T J of the free parameters (`names` frozen), in
    their own units (not the solver's reparametrisation)."""
    parameters = free_parameters(model, lambda name: name in names)
    if not parameters:
        return 0.0, jnp.zeros((0, 0))
    flat, rebuilt = as_vector(model, parameters)

    def residuals(theta):
        fitted = rebuilt(theta)
        return _masked_residuals(fitted, samples, mask, predict).reshape(-1)

    jacobian = jax.jacfwd(residuals)(flat)
    residual = residuals(flat)
    dof = jnp.maximum(jnp.sum(mask) * samples.values.shape[-1] - flat.shape[0], 1)
    return jnp.sum(residual * residual) / dof, gram(jacobian)


def standard_errors(model, samples, predict: Predict, freeze: Sequence[str] = ()) -> dict:
    """The standard error of every free parameter of a fitted `model` on `samples` (as
    `fit_model` fitted it; `freeze` as there), by dotted name: the Gauss-Newton covariance
    scaled by the residuals' variance. None where the data do not determine a parameter (a
    zero or rank-deficient column of the Jacobian: sigma where every F_tilde is 0)."""
    model = strongly_typed(model)
    names = tuple(freeze)
    samples, mask = padded(samples, len(samples.values))
    scale, information = _information(model, samples, mask, predict, names)
    parameters = free_parameters(model, lambda name: name in names)
    return named_errors(model, parameters, float(scale), np.asarray(information, np.float64))


# The default solver (Levenberg-Marquardt on the Jacobian matrix, `ctjax.solvers.DenseLM`):
# residuals are in the user's units (8-bit levels for images), and so are these tolerances.
LEVENBERG_MARQUARDT = DenseLM(rtol=1e-6, atol=1e-6)


def fit_model(
    starts: eqx.Module | Sequence[eqx.Module],
    samples,
    predict: Predict,
    *,
    columns: Callable | None = None,
    freeze: Sequence[str] = (),
    solver: Solver = LEVENBERG_MARQUARDT,
    max_steps: int = 100,
    refine: int = 1,
    scale: float = 255.0,
    unit: str = "8-bit levels",
) -> Estimate:
    """Fit a model to `samples` (anything with `.values` (N, 3) that `predict` reads).

    `starts` are one or several initial models of the same structure (e.g. different
    roughness or light offsets). With `columns`, each start first gets its linear weights in
    closed form (cheap), and LM then runs from the `refine` best starts; the best fit wins.
    `freeze` names parameters held fixed (dotted names, see `free_parameters`). `solver` is
    any optimistix least-squares solver or a `ctjax.solvers` object (default: `DenseLM`,
    Levenberg-Marquardt with tolerances in the reported units). `scale` converts residuals
    to the reported units (255: 8-bit levels; 1 for measured BRDFs), and `unit` names the
    result (e.g. "1/sr" for BRDF data).

    Returns an `Estimate`: the best fit, its RMSE on `samples` (`rmse["calibration"]`), its
    `cost`, and the solver's `Status` ("successful", "max_steps_reached", "singular",
    ...); `details` holds the number of steps and the free parameters' names. A failed fit
    is reported as `Status.failed` with an infinite cost, never returned as a success.
    """
    if isinstance(starts, eqx.Module):
        starts = [starts]
    starts = list(starts)
    names = tuple(freeze)
    measured = samples.values.size
    samples, mask = padded(samples, len(samples.values))
    if columns is not None or len(starts) > refine:
        ranked = [_started(m, samples, mask, predict, columns, float(scale)) for m in starts]
        starts = [m for m, _ in ranked]
        if len(starts) > refine:
            costs = [float(cost) for _, cost in ranked]
            starts = [starts[i] for i in np.argsort(costs)[:refine]]
    best = None
    for start in distinct(starts):
        fitted, cost, result, steps = _least_squares(
            start, samples, mask, predict, names, solver, max_steps, scale
        )
        cost = float(cost)
        if not np.isfinite(cost):
            continue
        if best is None or cost < best[1]:
            best = (fitted, cost, result, int(steps))
    if best is None:
        return Estimate(
            starts[0], {"calibration": math.inf}, Status.failed, cost=math.inf, unit=unit
        )
    fitted, cost, result, steps = best
    rmse = float(scale * np.sqrt(cost / measured))
    parameters = [p.name for p in free_parameters(fitted, lambda n: n in names)]
    return Estimate(
        fitted,
        {"calibration": rmse},
        Status(int(result)),
        cost=cost,
        unit=unit,
        details={"steps": steps, "parameters": parameters},
    )


def distinct(starts: Sequence[eqx.Module]) -> list[eqx.Module]:
    """`starts` with each model once (the first of equal ones): LM from a start equal to
    one already run ends where that one did. (`paper_model`'s sigma 0.2 is also one of
    `ROUGHNESS_STARTS`: the near light's starts at the lens ran LM twice from one point,
    15% of the sinus A's LM time.)"""
    kept = []
    for start in starts:
        if not any(bool(eqx.tree_equal(start, other)) for other in kept):
            kept.append(start)
    return kept


# Roughness values every start is also tried with: an effect the base model lacked has
# often bent its roughness (e.g. a camera gamma flattens the highlights), and the cost is
# not convex in it. Cheap: each start only costs a closed-form solve for the weights.
ROUGHNESS_STARTS = (0.1, 0.2, 0.35)


def roughness_variants(model) -> list:
    """`model`, and copies with every scalar microfacet-distribution parameter set to each
    of `ROUGHNESS_STARTS`; all strongly typed (see `strongly_typed`), so that they share
    one compilation of each fitter."""
    model = strongly_typed(model)
    scalars = [
        p
        for p in free_parameters(model)
        if ".distribution." in p.name and np.ndim(p.get(model)) == 0
    ]
    variants = [model]
    for value in ROUGHNESS_STARTS if scalars else ():
        variants.append(
            eqx.tree_at(
                lambda m: [p.get(m) for p in scalars],
                model,
                [jnp.asarray(value, p.get(model).dtype) for p in scalars],
            )
        )
    return variants


def pixel_predict(model, sample) -> Float[Array, "3"]:
    """`Predict` for `PixelSamples` and a `ShadingModel`."""
    return model(sample.point, sample.normal, sample.pixel, sample.frame)


def pixel_columns(model, sample) -> Float[Array, " K"]:
    """Linear design row for `PixelSamples` and a `ShadingModel`."""
    return model.columns(sample.point, sample.normal, sample.pixel)


__all__ = [
    "Parameter",
    "fit_model",
    "named_errors",
    "pixel_columns",
    "pixel_predict",
    "roughness_variants",
    "standard_errors",
]
