"""Estimating the BRDF (paper section 4, eq. 4-6): closed-form weights, grid BnB over the
nonlinear parameters, standard errors from the Jacobian at the optimum."""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._buckets import padded
from .._errors import CtjaxError
from .._programs import persistent_jit
from .._typing import Array, Float, Scalar
from ..lobes import BRDF, Beckmann, Lambertian, Specular, cook_torrance_brdf
from ..solvers._gram import gram
from ._branch_and_bound import grid_search
from ._closed_form import nnls_columns
from ._samples import ShadingSamples


class BRDFFamily(eqx.Module):
    """A BRDF up to its linear weights: `build(params)` for nonlinear `params` (D,) in the
    box [lo, hi]. The weights of the returned BRDF are ignored (estimated in closed form)."""

    build: Callable[[Float[Array, " D"]], BRDF] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    lo: tuple[float, ...] = eqx.field(static=True)
    hi: tuple[float, ...] = eqx.field(static=True)
    weight_names: tuple[str, ...] = eqx.field(static=True)
    # The diffuse lobe the family's BRDFs have (`with_diffuse`): the model without the
    # specular lobes, against which their gain counts, is this lobe alone.
    diffuse: type[Lambertian] = eqx.field(static=True, default=Lambertian)


# The weights a family's `build` gives its lobes, which `with_weights` replaces (and the
# columns, unit weight, never read): host data, so that building a fitted BRDF on the host
# runs no eager JAX op (a Python float would be broadcast to the channels by one).
_UNIT = np.ones(3)


def _paper(params):
    return cook_torrance_brdf(_UNIT, _UNIT, params[0])


def _lambertian(params):
    del params
    return BRDF(Lambertian(_UNIT))


def _two_scales(params):
    return BRDF(
        Lambertian(_UNIT),
        Specular(_UNIT, Beckmann(params[0])),
        Specular(_UNIT, Beckmann(params[1])),
    )


PAPER = BRDFFamily(_paper, ("sigma",), (1e-5,), (1.0,), ("rho_tilde", "F_tilde"))
LAMBERTIAN = BRDFFamily(_lambertian, (), (), (), ("rho_tilde",))
TWO_SCALES = BRDFFamily(
    _two_scales,
    ("sigma_1", "sigma_2"),
    (1e-5, 1e-5),
    (1.0, 1.0),
    ("rho_tilde", "F_tilde_1", "F_tilde_2"),
)


def _qualified(value) -> str:
    return f"{value.__module__}.{value.__qualname__}"


@dataclasses.dataclass(frozen=True)
class _WithDiffuse:
    """`build`'s BRDF with its Lambertian lobe replaced by `lobe(weight, *shape)`, the last
    `count` parameters being the lobe's shape. Compared by value and shown without an address
    (its programs compile once and are kept on disk, `ctjax._programs`)."""

    build: Callable[[Float[Array, " D"]], BRDF]
    lobe: type[Lambertian]
    count: int

    def __call__(self, params):
        from ..lobes._diffuse import with_diffuse_lobe

        own = params.shape[0] - self.count
        shape = [params[own + i] for i in range(self.count)]
        return with_diffuse_lobe(self.build(params[:own]), self.lobe, shape)

    def __repr__(self) -> str:
        return f"_WithDiffuse({_qualified(self.build)}, {_qualified(self.lobe)}, {self.count})"


def with_diffuse(family: BRDFFamily, lobe: type[Lambertian]) -> BRDFFamily:
    """`family` with `lobe` (a `Lambertian` subclass, `ctjax.lobes.diffuse_lobes`) as its
    diffuse term: the lobe's shape parameters join the search, in the boxes of their
    domains, after the family's own (`PAPER` with Oren-Nayar: sigma, then
    oren_nayar_roughness). `Lambertian` gives `family` itself."""
    from ..lobes._diffuse import diffuse_parameters

    if lobe is Lambertian:
        return family
    if family.diffuse is not Lambertian:
        raise CtjaxError(f"the family {family.names} has a diffuse term already")
    if not (isinstance(lobe, type) and issubclass(lobe, Lambertian)):
        raise CtjaxError(f"a diffuse term is a Lambertian lobe's subclass, got {lobe!r}")
    shape = diffuse_parameters(lobe)
    return BRDFFamily(
        _WithDiffuse(family.build, lobe, len(shape)),
        family.names + tuple(name for name, _, _ in shape),
        family.lo + tuple(lo for _, lo, _ in shape),
        family.hi + tuple(hi for _, _, hi in shape),
        family.weight_names,
        lobe,
    )


def diffuse_alone(family: BRDFFamily) -> BRDFFamily:
    """The family's diffuse lobe without the specular ones (`LAMBERTIAN` for the paper's):
    the model against which the lobes' gain counts."""
    return with_diffuse(LAMBERTIAN, family.diffuse)


def diffuse_note(family: BRDFFamily) -> str:
    """What a fit's `model` description adds for a diffuse term other than Lambert's."""
    if family.diffuse is Lambertian:
        return ""
    return (
        f"; the diffuse term {family.diffuse.diffuse_name} ({family.diffuse.__name__}, "
        "its shape fitted) instead of rho_tilde N.L/pi"
    )


class BRDFFit(eqx.Module):
    """The estimate: nonlinear `params` (D,), linear `weights` (K, 3), the cost (sum of
    squared residuals, linear units), their standard errors, and the fitted BRDF."""

    params: Float[Array, " D"]
    weights: Float[Array, "K 3"]
    cost: Scalar
    rgb_rmse: Scalar  # 8-bit levels
    params_stderr: Float[Array, " D"]
    weights_stderr: Float[Array, "K 3"]
    search_half_width: Float[Array, " D"]
    n_samples: int = eqx.field(static=True)
    family: BRDFFamily = eqx.field(static=True)

    @property
    def brdf(self) -> BRDF:
        return self.family.build(self.params).with_weights(self.weights)


def design_geometry(family: BRDFFamily, samples: ShadingSamples) -> tuple:
    """Each lobe's `geometry` at every sample (see `AbstractLobe.geometry`): what the
    design columns take of the samples whatever the nonlinear parameters, computed once for
    a search over them."""
    # A lobe's geometry reads none of its parameters: any value in the box builds the lobes.
    middle = (np.asarray(family.lo, float) + np.asarray(family.hi, float)) / 2
    brdf = family.build(jnp.asarray(middle, samples.irradiance.dtype))
    return jax.vmap(brdf.geometry)(samples.normal, samples.light, samples.view)


def design_columns(
    family: BRDFFamily, params, samples: ShadingSamples, geometry: tuple | None = None
) -> tuple[Array, ...]:
    """Each lobe's radiance at each sample for unit weight, times the irradiance: K (N,)
    arrays. `geometry` is `design_geometry(family, samples)` when the same samples are
    evaluated for many `params` (computed here otherwise). Lobes that do not depend on
    `params` give columns that stay unbatched under a `vmap` over `params` (computed once)."""
    geometry = design_geometry(family, samples) if geometry is None else geometry
    columns = jax.vmap(family.build(params).columns_given)(geometry)
    return tuple(samples.irradiance * column for column in columns)


def design_matrix(family: BRDFFamily, params, samples: ShadingSamples) -> Float[Array, "N K"]:
    """`design_columns` stacked as an (N, K) matrix."""
    return jnp.stack(design_columns(family, params, samples), axis=-1)


def _standard_errors(family, params, weights, samples, cost, count):
    """sqrt(diag(s^2 (J^T J)^-1)) for all parameters, J the Jacobian of the residuals;
    `count` residuals are real (padding rows have zero residuals and Jacobian)."""
    k = weights.shape[0]

    def residuals(theta):
        w = theta[: 3 * k].reshape(k, 3)
        p = theta[3 * k :]
        return (samples.values - design_matrix(family, p, samples) @ w).reshape(-1)

    theta = jnp.concatenate([weights.reshape(-1), params])
    jacobian = jax.jacfwd(residuals)(theta)
    dof = jnp.maximum(count - theta.shape[0], 1)
    information = gram(jacobian)
    covariance = cost / dof * jnp.linalg.pinv(information, hermitian=True)
    variance = jnp.diagonal(covariance)
    # A direction the data do not constrain (singular information) has no standard error.
    rank_deficient = jnp.linalg.matrix_rank(information) < theta.shape[0]
    stderr = jnp.where(rank_deficient | (variance < 0), jnp.inf, jnp.sqrt(jnp.abs(variance)))
    return stderr[3 * k :], stderr[: 3 * k].reshape(k, 3)


def _padded(samples: ShadingSamples) -> ShadingSamples:
    """`samples` padded to a bucket size (`ctjax._buckets`: captures share one compiled
    fit); the padding rows have zero irradiance and values, so they add nothing to any cost,
    design or Jacobian."""
    n = len(samples)
    samples, real = padded(samples, n)
    return eqx.tree_at(
        lambda s: (s.irradiance, s.values),
        samples,
        (jnp.where(real, samples.irradiance, 0), jnp.where(real[:, None], samples.values, 0)),
    )


@persistent_jit
def _fit(samples, count, family, tolerance, grid, candidates, zoom):
    """The BnB on (padded) `samples`, of which `count` values (3 per real sample) count."""

    geometry = design_geometry(family, samples)  # once for every params the search tries

    def cost(params):
        return nnls_columns(design_columns(family, params, samples, geometry), samples.values)[1]

    if family.names:
        search = grid_search(
            cost,
            family.lo,
            family.hi,
            tolerance=tolerance,
            grid=grid,
            candidates=candidates,
            zoom=zoom,
            dtype=samples.values.dtype,
        )
        params, half_width = search.params, search.half_width
    else:
        params = jnp.zeros((0,), samples.values.dtype)
        half_width = params
    weights, best_cost = nnls_columns(design_columns(family, params, samples), samples.values)
    params_stderr, weights_stderr = _standard_errors(
        family, params, weights, samples, best_cost, count
    )
    rmse = 255 * jnp.sqrt(best_cost / count)
    return params, weights, best_cost, rmse, params_stderr, weights_stderr, half_width


@persistent_jit
def _brightness_sums(samples, family, params, weights):
    predicted = design_matrix(family, params, samples) @ weights
    return jnp.sum(samples.values * predicted, -1), jnp.sum(predicted * predicted, -1)


def brightness_sums(fit: BRDFFit, samples: ShadingSamples) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, measured times predicted and predicted squared under `fit` (summed over
    the channels), (N,) each: a group of samples' gain (measured over predicted brightness,
    least squares) is the ratio of their sums."""
    across, power = _brightness_sums(_padded(samples), fit.family, fit.params, fit.weights)
    n = len(samples)
    return np.asarray(across, float)[:n], np.asarray(power, float)[:n]


def fit_brdf(
    samples: ShadingSamples,
    family: BRDFFamily = PAPER,
    *,
    tolerance: float = 1e-3,
    grid: int = 32,
    candidates: int = 4,
    zoom: int = 2,
) -> BRDFFit:
    """Estimate a BRDF from shading samples (paper eq. 5): the closed-form BnB.

    The linear weights are the exact nonnegative least-squares solution for each value of the
    nonlinear parameters (sigma, shared by the colour channels); the nonlinear parameters are
    found by a zooming grid over the family's box down to `tolerance` (paper: [1e-5, 1], 1e-3),
    keeping `candidates` intervals per level (see `grid_search`; `grid=10, candidates=1,
    zoom=1` reproduces the paper's BnB centre for centre). One compiled function.
    """
    if len(samples) == 0:
        raise CtjaxError("no samples to fit the BRDF on (empty ring)")
    values = np.asarray(samples.values)
    if not np.all(np.isfinite(values)):
        raise CtjaxError("sample values contain NaN or inf")
    k = len(family.weight_names)
    if len(samples) < k + len(family.names) + 1:
        raise CtjaxError(
            f"{len(samples)} samples cannot determine {k * 3 + len(family.names)} parameters"
        )
    count = jnp.asarray(values.size, values.dtype)
    params, weights, cost, rmse, p_err, w_err, half_width = _fit(
        _padded(samples), count, family, tolerance, grid, candidates, zoom
    )
    return BRDFFit(params, weights, cost, rmse, p_err, w_err, half_width, len(samples), family)
