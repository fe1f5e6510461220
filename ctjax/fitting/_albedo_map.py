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
import optimistix as optx

from .._errors import ParameterError
from .._result import Estimate
from .._status import Status
from .._tracks import Tracks
from .._vector import Vec3
from ..estimation._albedo_map import projected_residuals
from ..lobes import Lambertian
from ._fit import LEVENBERG_MARQUARDT
from ._parameters import constrained, free_parameters, strongly_typed, unconstrained


class TrackSamples(eqx.Module):
    """Tracks as the general fitter sees them: every observation's four corners flattened
    (P * M * 4: camera-frame point, normal, pixel), their bilinear weights (P, M, 4), the
    measured RGB (P, M, 3) and each observation's least-squares weight (P, M)."""

    point: Vec3
    normal: Vec3
    pixel: tuple
    corner_weight: jax.Array
    values: jax.Array
    weight: jax.Array

    @classmethod
    def of(cls, tracks: Tracks, dtype=None) -> "TrackSamples":
        dtype = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
        as_jax = lambda a: jnp.asarray(a, dtype)  # noqa: E731
        flat = lambda a: as_jax(a.reshape(-1, a.shape[-1]))  # noqa: E731
        pixel = flat(tracks.corner_pixel)
        return cls(
            Vec3.from_array(flat(tracks.corner_point)),
            Vec3.from_array(flat(tracks.corner_normal)),
            (pixel[:, 0], pixel[:, 1]),
            as_jax(tracks.corner_weight),
            as_jax(tracks.values),
            as_jax(tracks.weight),
        )


def diffuse_lobe(model) -> int:
    """Index of the lobe whose weight is per point: the (first) Lambertian one."""
    for index, lobe in enumerate(model.brdf.lobes):
        if isinstance(lobe, Lambertian):
            return index
    raise ParameterError("an albedo map needs a Lambertian lobe in the model's BRDF")


def _columns(model, samples: TrackSamples):
    p, m, _ = samples.corner_weight.shape
    columns = jax.vmap(model.columns)(samples.point, samples.normal, samples.pixel)
    columns = columns.reshape(p, m, 4, -1)
    combined = jnp.einsum("pmck,pmc->pmk", columns, samples.corner_weight)
    return tuple(combined[..., k] for k in range(combined.shape[-1]))


def _weights_frozen(name: str) -> bool:
    return name.startswith("brdf.lobes[") and name.endswith("].weight")


@eqx.filter_jit
def _least_squares(model, samples, names, per_point, solver, max_steps):
    freeze = lambda name: name in names or _weights_frozen(name)  # noqa: E731
    parameters = free_parameters(model, freeze)

    def residuals(u, _):
        fitted = constrained(model, parameters, u)
        _, _, residual = projected_residuals(
            _columns(fitted, samples), samples.values, samples.weight, per_point
        )
        return 255 * residual.reshape(-1)  # 8-bit levels: so are the tolerances

    solution = optx.least_squares(
        residuals, solver, unconstrained(model, parameters), max_steps=max_steps, throw=False
    )
    fitted = constrained(model, parameters, solution.value)
    albedo, weights, residual = projected_residuals(
        _columns(fitted, samples), samples.values, samples.weight, per_point
    )
    cost = jnp.sum(residual * residual)
    return (
        fitted,
        albedo,
        weights,
        cost,
        Status.of_optimistix(solution.result),
        (solution.stats["num_steps"]),
    )


def fit_model_map(
    starts: eqx.Module | Sequence[eqx.Module],
    tracks: Tracks | TrackSamples,
    *,
    freeze: Sequence[str] = (),
    solver: optx.AbstractLeastSquaresSolver = LEVENBERG_MARQUARDT,
    max_steps: int = 100,
) -> Estimate:
    """Fit `ShadingModel`s (one or several starts of the same structure) to tracked surface
    points with one albedo per point (the diffuse lobe's weight) and the other lobes' weights
    shared, both eliminated in closed form; LM runs over the remaining parameters (`freeze`
    holds more fixed). Models with image effects are refused (an effect after the sum of
    lobes makes the albedo nonlinear).

    Returns an `Estimate` of the best start: the model with its global weights and, in the
    diffuse lobe, the median albedo of the points seen twice or more; `rmse["calibration"]`
    the weighted RMSE (8-bit levels) over the observations; `arrays["track_albedo"]` every
    point's albedo (P, 3); `details["albedo"] = "map"`.
    """
    starts = [starts] if isinstance(starts, eqx.Module) else list(starts)
    for start in starts:
        if getattr(start, "effects", ()):
            raise ParameterError(
                "fit_model_map fits models without image effects (an effect after the lobes "
                "makes the albedo nonlinear); fit the effect with fit_model"
            )
    samples = tracks if isinstance(tracks, TrackSamples) else TrackSamples.of(tracks)
    views = np.asarray(jnp.sum(samples.weight > 0, axis=1))
    per_point = diffuse_lobe(starts[0])
    best = None
    for start in starts:
        fitted, albedo, weights, cost, result, steps = _least_squares(
            strongly_typed(start), samples, tuple(freeze), per_point, solver, max_steps
        )
        cost = float(cost)
        if np.isfinite(cost) and (best is None or cost < best[3]):
            best = (fitted, albedo, weights, cost, result, int(steps))
    if best is None:
        return Estimate(starts[0], {"calibration": math.inf}, Status.failed, cost=math.inf)
    fitted, albedo, weights, cost, result, steps = best
    albedo = np.asarray(albedo)
    weights = np.asarray(weights).copy()
    seen = views > 1
    weights[per_point] = np.median(albedo[seen], axis=0) if seen.any() else 0.0
    brdf = fitted.brdf.with_weights(jnp.asarray(weights, fitted.brdf.weights.dtype))
    fitted = eqx.tree_at(lambda m: m.brdf, fitted, brdf)
    total_weight = float(jnp.sum(samples.weight)) * samples.values.shape[-1]
    rmse = 255 * math.sqrt(cost / max(total_weight, 1e-300))
    parameters = [
        p.name for p in free_parameters(fitted, lambda n: n in tuple(freeze) or _weights_frozen(n))
    ]
    return Estimate(
        fitted,
        {"calibration": rmse},
        Status(int(result)),
        cost=cost,
        details={"steps": steps, "parameters": parameters, "albedo": "map"},
        arrays={"track_albedo": albedo},
    )
