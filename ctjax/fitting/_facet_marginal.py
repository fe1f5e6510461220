"""The facet lobe by its marginal likelihood: every tracked point's facet integrated out.

`facet_lobe` chooses the lobe that best predicts each view from the point's other views,
each point's facet chosen among candidates; against synthetic truth its sigma reads within
20% and its F_tilde 30-80% low (choosing the facet per point is a nuisance parameter per
point: Neyman and Scott's bias). Here the facet is a random effect instead. A point's
facet m is drawn from a Beckmann distribution of width `sigma_M` about the reconstruction's
normal (the tissue's relief, which the reconstruction does not resolve); its views are the
diffuse term (the point's albedo per channel, profiled) plus the lobe of roughness sigma and
weight F_tilde about m; each value has Gaussian noise of scale s (or Student-t's, `nu`
degrees of freedom, for heavy tails: clipped cores, texture and registration errors). A point's
likelihood is

    p(views) = (1 - mass) p(views | no lobe) + sum over nodes of p(m) dOmega p(views | m)

a quadrature over the facets near the arc the point's H trace (`FACET_NODES`: along the arc
from 3 sigma before the first view's H to 3 sigma after the last, and 3 sigma across it), the
rest of the prior's mass lighting none of the views. The product over the points is the
likelihood of (sigma, F_tilde, sigma_M, s); sigma and F_tilde are its maximum on a grid, the
nuisances sigma_M and s profiled, refined between the grid's points (`chosen_on_grid`), and again
on the even and on the odd calibration frames alone (the status, as `facet_lobe`'s).

Measured against synthetic truth and on the real sequences: `FacetMarginal`,
docs/real-video.md ("The facets integrated out").
"""

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._buckets import bucket
from .._convert import on_device
from .._determined import PRIORITY
from .._errors import ParameterError
from .._programs import persistent_jit
from .._status import Status
from ._drift import FIRST, SECOND, boundary_of, drift_reasons, in_subset
from ._facet_geometry import grouped_per_point, half_vectors, lobe_columns, views_arc
from ._facet_lobe import (
    FACET_F_TILDES,
    FACET_SIGMAS,
    chosen_on_grid,
    halves_json,
    views_step,
    views_step_json,
)
from ._facet_status import (
    MIN_FRAMES_FOR_HALVES,
    F_tilde_reasons,
    facet_status,
    nuisance_reasons,
)
from ._facets import facet_arguments, facet_model
from ._map_least_squares import TrackSamples, diffuse_lobe
from ._profiled_albedo import gaussian_nll, gaussian_ssr, view_sums

# The facets' spread about the reconstruction's normal (Beckmann widths): from a smooth
# surface to a rough one. Up to 0.7 at first: both real sequences put it at that top
# (`at_bound`); with the grid to 2.0 the shared sinus's 12 frames take 0.7 inside it (sigma
# 0.0758 for 0.0753, `unstable` only: its halves 40% apart).
FACET_PRIOR_SIGMAS = (0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 1.4, 2.0)
# The noise scales profiled by default, multiples of `noise_scale`'s: Student-t's (few: each
# scale costs a pass), the Gaussian's (many: one sum of squares serves them all). On
# attached synthetic sparkles (1 level of Gaussian noise, micro-lobe 0.06, F_tilde 0.012;
# 32 x 9 nodes, not refined) Student-t with 4 degrees of freedom takes the least scale, 0.75
# levels, and reads F_tilde 0.019 (at 1 level: 0.0117): heavy tails let a strong lobe
# mispredict cheaply.
# Down to 0.3 for the Gaussian: SCARED's frames 61-72 put the scale at 0.7, the grid's bottom
# then (3.18 levels; `at_bound`), and the lobe-free residuals' median is the highlights'
# misfit as much as the camera's noise.
NOISE_MULTIPLES = {
    False: (1.0, 1.4, 2.0),
    True: (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.25, 1.4, 1.6, 1.8, 2.0, 2.5, 3.0, 4.0),
}
# Student-t's degrees of freedom for heavy-tailed noise (`nu`; the default noise is Gaussian).
STUDENT_NU = 4.0
# Quadrature nodes per point: along the views' arc, and across it.
FACET_NODES = (32, 9)
# Each of the 3 x 3 coarse cells about a point's likeliest node split this many times
# along and across (`facet_marginal`'s `refine`).
FACET_REFINE = 5
_POINTS_AT_ONCE = 128


def _node_frame(h, w):
    """The quadrature's frame about one point's views' H (M, 3): their mean direction,
    the arc they trace (`views_arc`) and the direction across it."""
    counted = (w > 0)[:, None]
    centre = jnp.sum(jnp.where(counted, h, 0), 0) + jnp.asarray([0, 0, 1e-9], h.dtype)
    centre = centre / jnp.linalg.norm(centre)
    arc = views_arc(h, w)
    arc = arc - (arc @ centre) * centre
    arc = arc / jnp.maximum(jnp.linalg.norm(arc), 1e-12)
    return centre, arc, jnp.cross(centre, arc)


def _one_point(
    model, rotations, gains, subsets, boundary, sigma, prior_sigmas, noise, nu, nodes, refine,
    exact, point, normal, pixel, weight, values, w, frame, h,
):  # fmt: skip
    """One tracked point's log-likelihood (G, T, SM, NS) per set of lobe weights `gains`
    (G, K, C), subset of its frames (`subsets`: `_drift.in_subset`'s, the halves split at
    `boundary`), facet
    prior width `prior_sigmas` (SM,) and noise scale `noise` (NS,), and without the lobe
    (T, NS). The quadrature's nodes: a coarse grid over the views' arc (`nodes`), then the
    3 x 3 cells about its likeliest node (the middle set of weights, all frames) each split
    `refine` x `refine`: a point's likelihood is far narrower in its facet than the lobe
    when the lobe stands well above the noise. The sum over the nodes: a logsumexp
    (`exact`), or a product of matrices, with whether it underflowed (third)."""
    diffuse = diffuse_lobe(model)
    others = [k for k in range(len(model.brdf.lobes)) if k != diffuse]
    smooth, about = lobe_columns(model, "lobe", rotations, point, normal, pixel, weight, frame)
    counted = w > 0
    seen = jnp.any(counted)
    h = jnp.where(counted[:, None], h, 0.0)  # a view not counted may have no H
    centre, arc, across = _node_frame(h, w)
    u = h @ arc
    lo = jnp.where(seen, jnp.min(jnp.where(counted, u, jnp.inf)), 0.0) - 3 * sigma
    hi = jnp.where(seen, jnp.max(jnp.where(counted, u, -jnp.inf)), 0.0) + 3 * sigma
    along_n, across_n = nodes
    du, dv = (hi - lo) / (along_n - 1), 6 * sigma / (across_n - 1)
    # The reconstruction's normal in the world: the counted views' mean.
    local = jnp.sum(normal * weight[..., None], 0)  # (M, 3)
    world = jnp.einsum("mij,mj->mi", rotations[frame], local)
    world = jnp.sum(jnp.where(counted[:, None], world, 0), 0)
    world = world / jnp.maximum(jnp.linalg.norm(world), 1e-12)
    s2 = prior_sigmas[:, None] ** 2

    def at(steps_u, steps_v, area):
        """Facets (N, 3) at the nodes (along, across the arc) and their prior mass (SM, N)."""
        facets = centre + steps_u[:, None, None] * arc + steps_v[None, :, None] * across
        facets = facets.reshape(-1, 3)
        facets = facets / jnp.linalg.norm(facets, axis=-1)[:, None]
        cos = jnp.clip(facets @ world, 1e-3, 1.0)
        tan2 = (1 - cos * cos) / (cos * cos)
        # p(m) dOmega = D(m) cos(theta_m) dOmega, D Beckmann's: mass 1 over the hemisphere.
        log_prior = -tan2 / s2 - jnp.log(jnp.pi * s2) - 3 * jnp.log(cos) + jnp.log(area)
        return facets, log_prior

    subset_weights = jnp.stack(
        [w if s is None else jnp.where(in_subset(s, frame, boundary), w, 0.0) for s in subsets]
    )

    def lobes_of(x):  # the lobes other than the diffuse one: (..., K, ...) -> (..., K', ...)
        return x[..., jnp.array(others), :] if others else x[..., :0, :]

    def nll(columns, g, subset_weights, noise):  # (N, K, M) -> (N, T, NS)
        if nu is None:  # Gaussian: sums over the views that serve every weight and scale
            sums = view_sums(smooth[diffuse], lobes_of(columns), values, subset_weights)
            return gaussian_nll(gaussian_ssr(sums, lobes_of(g)), sums["count"], noise)

        def per_column(c):
            a = c[diffuse]
            rest = sum((c[k][None] * g[k][:, None] for k in others), jnp.zeros_like(values))
            target = values - rest  # (C, M)

            def per_subset(ws):
                b = jnp.where(ws > 0, a, 0.0)
                albedo = jnp.sum(ws * b * target, -1) / jnp.maximum(jnp.sum(ws * b * b), 1e-30)
                r2 = (target - jnp.maximum(albedo, 0.0)[:, None] * b) ** 2  # (C, M)
                scale2 = nu * noise * noise
                rho = (nu + 1) / 2 * jnp.log1p(r2[None] / scale2[:, None, None])  # (NS, C, M)
                rho = jnp.where(ws > 0, ws * (rho + jnp.log(noise)[:, None, None]), 0.0)
                return jnp.sum(rho, (1, 2))  # (NS,)

            return jax.vmap(per_subset)(subset_weights)

        return jax.vmap(per_column)(columns)

    grid_u = lo + du * jnp.arange(along_n, dtype=h.dtype)
    grid_v = -3 * sigma + dv * jnp.arange(across_n, dtype=h.dtype)
    coarse, coarse_prior = at(grid_u, grid_v, du * dv)
    coarse_columns = jax.vmap(about)(coarse)
    # The likeliest coarse node for the middle weights and scales, all the frames.
    middle = len(prior_sigmas) // 2, noise.shape[0] // 2
    score = -nll(coarse_columns, gains[gains.shape[0] // 2], w[None], noise[middle[1]][None])
    best = jnp.argmax(coarse_prior[middle[0]] + score[:, 0, 0])
    best_u, best_v = best // across_n, best % across_n
    fine = (jnp.arange(3 * refine, dtype=h.dtype) + 0.5) / refine - 1.5
    refined, refined_prior = at(
        grid_u[best_u] + du * fine, grid_v[best_v] + dv * fine, du * dv / refine**2
    )
    near = (jnp.abs(jnp.arange(along_n) - best_u) <= 1)[:, None] & (
        jnp.abs(jnp.arange(across_n) - best_v) <= 1
    )[None, :]
    coarse_prior = jnp.where(near.reshape(-1)[None], -jnp.inf, coarse_prior)
    log_prior = jnp.concatenate([coarse_prior, refined_prior], -1)  # (SM, N)
    mass = jnp.clip(jnp.sum(jnp.exp(log_prior), -1), 0.0, 1 - 1e-6)  # (SM,)
    log_weights = jnp.concatenate([jnp.log1p(-mass)[:, None], log_prior], -1)  # (SM, N + 1)
    off = smooth.at[jnp.array(others)].set(0.0) if others else smooth
    columns = jnp.concatenate([off[None], coarse_columns, jax.vmap(about)(refined)])

    if nu is None and not exact:
        sums = view_sums(smooth[diffuse], lobes_of(columns), values, subset_weights)

    def per_gain(g):
        if exact or nu is not None:
            costs = nll(columns, g, subset_weights, noise)  # (N + 1, T, NS)
        if exact:
            joint = log_weights[None, :, None, :] - jnp.moveaxis(costs, 0, -1)[:, None]
            ll = jax.scipy.special.logsumexp(joint, -1)  # (T, SM, NS)
            return ll, jnp.asarray(False), -costs[0]
        if nu is None:  # each node's excess over the least sum of squares, scaled per noise
            ssr = gaussian_ssr(sums, lobes_of(g))  # (N + 1, T)
            least = jnp.min(ssr, 0)
            excess = jnp.exp(-(ssr - least)[..., None] / (2 * noise * noise))  # (N + 1, T, NS)
            best = gaussian_nll(least, sums["count"], noise)  # (T, NS)
            without = -gaussian_nll(ssr[0], sums["count"], noise)
        else:
            best = jnp.min(costs, 0)  # (T, NS)
            excess, without = jnp.exp(best - costs), -costs[0]
        return *_over_the_nodes(log_weights, excess, best), without

    ll, underflow, without = jax.vmap(per_gain)(gains)
    return jnp.where(seen, ll, 0.0), jnp.where(seen, without[0], 0.0), jnp.any(underflow) & seen


def _over_the_nodes(log_weights, excess, best):
    """log sum_n exp(log_weights[s, n] - cost[n, t, k]) (T, SM, NS), the costs given as
    `best` (T, NS), their least over the nodes, and `excess` (N, T, NS) = exp(best - cost):
    a product of matrices, each factor scaled by its largest value. One exponential per
    node, weights and scale, where the logsumexp takes one per prior width too (8x as many:
    90% of `facet_marginal`'s time). Second: whether the sum came within a factor 1/eps of
    the smallest normal number (the likeliest nodes e^-700 below the prior's peak, e^-87 in
    float32), where it may have lost terms (`_marginal` then takes the logsumexp)."""
    top = jnp.max(log_weights, -1)  # (SM,)
    prior = jnp.exp(log_weights - top[:, None])
    total = jnp.einsum("sn,ntk->tsk", prior, excess)
    smallest = jnp.finfo(total.dtype).tiny / jnp.finfo(total.dtype).eps
    return jnp.log(total) + top[:, None] - best[:, None], jnp.any(total < smallest)


@persistent_jit
def _lambertian_residuals(model, samples, judged, rotations, candidates):
    """Every counted value's residual (C, M, P) under the model without its lobe, each
    point's albedo fitted to its views, and the views' weights (M, P)."""
    arrays = grouped_per_point(model, samples, judged, rotations, candidates)
    point, normal, pixel, weight, values, w, _, frame, _ = arrays
    diffuse = diffuse_lobe(model)

    def one(point, normal, pixel, weight, values, w, frame):
        smooth, _ = lobe_columns(model, "lobe", rotations, point, normal, pixel, weight, frame)
        a = jnp.where(w > 0, smooth[diffuse], 0.0)
        albedo = jnp.sum(w * a * values, -1) / jnp.maximum(jnp.sum(w * a * a), 1e-30)
        return jnp.where(w > 0, values - jnp.maximum(albedo, 0.0)[:, None] * a, 0.0)

    residual = jax.vmap(one)(point, normal, pixel, weight, values, w, frame)
    return jnp.moveaxis(residual, 0, -1), w.T


def _median_abs_t(nu: float | None) -> float:
    """The median of |t| for Student's t with `nu` degrees of freedom and unit scale (0.741
    for 4; None: the Gaussian's, 0.674), by quadrature of its density."""
    if nu is None:
        return 0.6744897501960817
    x = np.concatenate([[0.0], np.geomspace(1e-4, 1e6, 200_001)])
    density = (1 + x * x / nu) ** (-(nu + 1) / 2)
    mass = np.concatenate([[0.0], np.cumsum(np.diff(x) * (density[1:] + density[:-1]) / 2)])
    return float(np.interp(0.5 * mass[-1], mass, x))


def noise_scale(train: TrackSamples, rotations, light, nu: float | None = None) -> float:
    """The noise's scale (8-bit levels) of `train`'s values about the Lambertian model
    under `light`, each point's albedo fitted to its views: their median absolute residual
    over that of the noise's law (Student-t with `nu` degrees of freedom; None: Gaussian),
    robust to the highlights the model lacks."""
    model, judged, rotated, _, candidates, _ = facet_arguments(
        facet_model(light, 0.1, 0.0), train, np.asarray(train.weight) > 0, rotations, None,
        0.0, None, (0.0,),
    )  # fmt: skip
    residual, w = _lambertian_residuals(model, train, judged, rotated, candidates)
    counted = np.broadcast_to(np.asarray(w) > 0, residual.shape)
    values = np.abs(np.asarray(residual)[counted])
    if values.size == 0:
        raise ParameterError("no tracked point has a view to measure the noise on")
    return 255 * float(np.median(values)) / _median_abs_t(nu)


def _observed_points(train: TrackSamples) -> TrackSamples:
    """`train` with only its points that have a view, padded to a `bucket` with one that
    has none: a point without views adds nothing to the likelihood, and the tracks come
    padded (27% of a 256x192 capture's 16384 columns were empty when they came padded to
    a power of two; to a `bucket` since 2026-12-06). Every
    array of `TrackSamples` has the points last, some flattened (4 M P); the columns are
    taken on the host."""
    seen = np.asarray(train.weight).sum(0) > 0
    observed, empty = np.flatnonzero(seen), np.flatnonzero(~seen)
    points, size = seen.size, bucket(len(observed))
    if size >= points or empty.size == 0:
        return train
    columns = np.concatenate([observed, np.full(size - len(observed), empty[0])])

    def taken(a):
        a = np.asarray(a)
        kept = a.reshape(-1, points)[:, columns]
        return on_device(kept.reshape((*a.shape[:-1], size) if a.shape[-1] == points else -1))

    return jax.tree.map(taken, train)


@persistent_jit
def _marginal(model, samples, judged, rotations, candidates, gains, sigma, prior_sigmas,
              noise, nu: float | None, subsets: tuple, boundary, nodes: tuple,
              refine: int):  # fmt: skip
    """Every tracked point's `_one_point`: (P, G, T, SM, NS) and (P, T, NS)."""
    arrays = grouped_per_point(model, samples, judged, rotations, candidates)
    point, normal, pixel, weight, values, w, _, frame, _ = arrays
    h = jax.vmap(lambda *a: half_vectors(model, rotations, *a))(point, pixel, weight, frame)

    def points(exact, x):
        def one(*a):
            options = (sigma, prior_sigmas, noise, nu, nodes, refine, exact)
            return _one_point(model, rotations, gains, subsets, boundary, *options, *a)

        return jax.vmap(one)(*x)

    arrays = (point, normal, pixel, weight, values, w, frame, h)
    return every_point(lambda x: points(False, x), lambda x: points(True, x)[:2], arrays)


def every_point(fast, exact, arrays, at_once: int = _POINTS_AT_ONCE, exact_at_once: int = 16):
    """`fast` over every point of `arrays` (leading axis P), `at_once` points a batch:
    (outputs, underflowed (P,)); then `exact` (the same outputs) on the points whose fast
    sums underflowed alone, `exact_at_once` at a time (a divisor of `at_once`): only as many
    batches as they fill. (A batch of `fast` taken again by `exact` wherever one of its
    points underflowed: 3.5x the time of `facet_marginal` on the cholecystectomy in
    float32, where a tenth of the points underflow.)"""
    count = jax.tree.leaves(arrays)[0].shape[0]
    batches = -(-count // at_once)
    padded = batches * at_once - count  # repeat the last point (a valid one)
    arrays = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], padded, 0)]), arrays)
    shaped = jax.tree.map(lambda a: a.reshape(batches, at_once, *a.shape[1:]), arrays)
    *out, underflow = (x.reshape(-1, *x.shape[2:]) for x in jax.lax.map(fast, shaped))
    order = jnp.argsort(jnp.where(underflow, 0, 1), stable=True)  # the underflowed first
    todo = -(-jnp.sum(underflow) // exact_at_once)

    def again(i, state):
        index = jax.lax.dynamic_slice(order, (i * exact_at_once,), (exact_at_once,))
        redo = underflow[index]  # the slice's last points may not have underflowed
        return tuple(
            kept.at[index].set(jnp.where(redo.reshape(-1, *[1] * (e.ndim - 1)), e, kept[index]))
            for kept, e in zip(state, exact(jax.tree.map(lambda a: a[index], arrays)), strict=True)
        )

    return tuple(x[:count] for x in jax.lax.fori_loop(0, todo, again, tuple(out)))


class FacetMarginal(eqx.Module):
    """The facet lobe by its marginal likelihood (`facet_marginal`): `sigma` and `F_tilde`
    (grey) at the likelihood's maximum on the calibration tracks, the nuisances there
    (`prior_sigma`, the facets' Beckmann width about the reconstruction's normal, and
    `noise_levels`, Student-t's scale in 8-bit levels), `log_likelihood` (grid point -> its
    maximum over the nuisances, nats), `gain_per_value` (nats per value over the model
    without a lobe), `halves` (the choice again on the even and on the odd calibration
    frames alone; None with fewer than 6), `contiguous_halves` (on the first and on the
    second half of them: `_drift`), `status` and `undetermined` as `FacetLobe`'s
    (the nuisances at an end of their grids are `at_bound` too: the likelihood then
    misdescribes the data; F_tilde's halves are checked as sigma's; no `no_lobe` check: a
    lobe the data do not want puts F_tilde at its grid's bottom), `at_bound` (sigma or
    F_tilde at an end of its grid), `views_step` (`FacetLobe.views_step`).

    Against synthetic truth (attached sparkles at 256x192 x 12, micro-lobe 0.06, F_tilde
    0.012, facets of Beckmann 0.2, 1 level of noise; `benchmarks/facet_truth.py
    --marginal`): sigma 0.0631, F_tilde 0.0160, sigma_M 0.2, the halves within 1% in both,
    `successful`; `--seed 2` sigma 0.0637, F_tilde 0.0206, sigma_M 0.1; over the variants
    tried (quadrature, noise law) sigma within 8% and F_tilde 0.010-0.021: F_tilde is read
    34-72% high by this one, an upper bound (docs/real-video.md). On the same captures
    `facet_lobe` reads 0.067 and 0.0084, 0.049 and 0.0039, `unstable`."""

    sigma: float
    F_tilde: float
    prior_sigma: float
    noise_levels: float
    log_likelihood: dict
    gain_per_value: float
    at_bound: bool
    halves: tuple | None = None
    status: str = "successful"
    undetermined: tuple = ()
    views_step: tuple = (math.nan, math.nan, math.nan)
    contiguous_halves: tuple | None = None

    @property
    def peak(self) -> float:
        """F_tilde / sigma^2 (`FacetLobe.peak`)."""
        return self.F_tilde / self.sigma**2

    def to_json(self) -> dict:
        halves = halves_json(self.halves)
        return {
            "sigma": self.sigma,
            "F_tilde": self.F_tilde,
            "peak": self.peak,
            "facet_prior_sigma": self.prior_sigma,
            "noise_levels": self.noise_levels,
            "gain_nats_per_value": self.gain_per_value,
            "status": self.status,
            "undetermined": list(self.undetermined),
            "at_bound": self.at_bound,
            "halves": halves,
            "contiguous_halves": halves_json(self.contiguous_halves, ("first_half", "second_half")),
            "views_step_rad": views_step_json(self.views_step),
            "log_likelihood": {
                f"sigma={s:g},F_tilde={f:g}": v for (s, f), v in self.log_likelihood.items()
            },
        }


def facet_marginal(
    train: TrackSamples,
    rotations,
    light,
    *,
    sigmas: Sequence[float] = FACET_SIGMAS,
    F_tildes: Sequence[float] = FACET_F_TILDES,
    prior_sigmas: Sequence[float] = FACET_PRIOR_SIGMAS,
    noise_levels: Sequence[float] | None = None,
    nu: float | None = None,
    nodes: tuple[int, int] = FACET_NODES,
    refine: int = FACET_REFINE,
    halves: bool = True,
) -> FacetMarginal:
    """The lobe about every point's facet, the facets integrated out (see the module):
    sigma and F_tilde at the maximum of the marginal likelihood of `train`'s views under
    `light` on the grid `sigmas` x `F_tildes`, with the facets' prior width (`prior_sigmas`)
    and the noise's scale (`noise_levels`, 8-bit levels; Student-t with `nu` degrees of
    freedom, None Gaussian; by default `NOISE_MULTIPLES` of `noise_scale`'s) profiled.
    `nodes`: the quadrature's nodes along and across the views' arc; `refine`: how many
    times each of the 3 x 3 cells about a point's likeliest node is split, along and
    across. `rotations` (F, 3, 3): every frame's camera-to-world rotation. `halves`: the
    choice again on the even and on the odd calibration frames alone."""
    grids = {"sigmas": sigmas, "F_tildes": F_tildes, "prior_sigmas": prior_sigmas,
             "noise_levels": (1.0,) if noise_levels is None else noise_levels}  # fmt: skip
    for name, grid in grids.items():
        values = np.asarray(grid, float)
        if values.ndim != 1 or values.size == 0 or not np.all(np.isfinite(values) & (values > 0)):
            raise ParameterError(f"facet_marginal's {name} must be positive numbers, got {grid}")
    if nu is not None and not (np.isfinite(nu) and nu > 0):
        raise ParameterError(f"facet_marginal's nu must be positive, got {nu}")
    if len(nodes) != 2 or min(int(n) for n in nodes) < 2:
        raise ParameterError(f"facet_marginal's nodes must be two counts >= 2, got {nodes}")
    nodes = (int(nodes[0]), int(nodes[1]))
    if int(refine) < 1:
        raise ParameterError(f"facet_marginal's refine must be at least 1, got {refine}")
    train = _observed_points(train)
    if noise_levels is None:
        base = noise_scale(train, rotations, light, nu)
        noise_levels = tuple(base * k for k in NOISE_MULTIPLES[nu is None])
    weight = np.asarray(train.weight)
    frames = len(np.unique(np.asarray(train.site.frame)[weight > 0]))
    checked = halves and frames >= MIN_FRAMES_FOR_HALVES
    subsets = (None, 0, 1, FIRST, SECOND) if checked else (None,)
    boundary = boundary_of(np.unique(np.asarray(train.site.frame)[weight > 0]))
    boundary = on_device(np.asarray(boundary, np.int32))
    dtype = train.weight.dtype
    prior = jnp.asarray(prior_sigmas, dtype)
    noise = jnp.asarray(np.asarray(noise_levels, float) / 255.0, dtype)
    likelihood, without = [], []
    for sigma in sigmas:
        model, judged, rotated, _, candidates, gains = facet_arguments(
            facet_model(light, sigma, F_tildes[0]), train, weight > 0, rotations, F_tildes,
            0.0, None, (0.0,),
        )  # fmt: skip
        ll, off = _marginal(
            model, train, judged, rotated, candidates, gains, jnp.asarray(sigma, dtype),
            prior, noise, None if nu is None else float(nu), subsets, boundary, nodes,
            int(refine),
        )  # fmt: skip
        likelihood.append(np.asarray(ll, float).sum(0))  # (G, T, SM, NS)
        without.append(np.asarray(off, float).sum(0))  # (T, NS)
    likelihood = np.stack(likelihood)  # (S, G, T, SM, NS)
    profiled = likelihood.max((3, 4))  # (S, G, T)
    keys = [(float(s), float(f)) for s in sigmas for f in F_tildes]

    def choice(t):
        return chosen_on_grid(
            dict(zip(keys, -profiled[:, :, t].ravel(), strict=True)), squared=False
        )

    sigma, f = choice(0)
    best = np.unravel_index(np.argmax(likelihood[:, :, 0]), likelihood[:, :, 0].shape)
    prior_sigma, noise_at = float(prior_sigmas[best[2]]), float(noise_levels[best[3]])
    values = 3 * float(np.sum(weight))
    gain = float((likelihood[:, :, 0].max() - without[0][0].max()) / values) if values else math.nan
    split = (choice(1), choice(2)) if checked else None
    contiguous = (choice(3), choice(4)) if checked else None
    unchecked = frames if halves and not checked else None
    step = views_step(train, rotations)
    _, reasons = facet_status(
        sigma, f, sigmas, F_tildes, math.nan, split, math.nan, unchecked, step
    )
    found = [
        *reasons,
        *(
            []
            if any(u["parameter"] == "sigma" for u in reasons)
            else drift_reasons(sigma, contiguous)
        ),
        *F_tilde_reasons(f, split, F_tildes),
        *nuisance_reasons("sigma_M", "facets' prior width sigma_M", prior_sigma, prior_sigmas),
        *nuisance_reasons("noise_levels", "noise's scale", noise_at, noise_levels),
    ]
    statuses = [Status[u["status"]] for u in found]
    status = min(statuses, key=PRIORITY.index).name if found else Status.successful.name
    at_bound = not (min(sigmas) < sigma < max(sigmas) and min(F_tildes) < f < max(F_tildes))
    return FacetMarginal(
        sigma,
        f,
        prior_sigma,
        noise_at,
        dict(zip(keys, profiled[:, :, 0].ravel().tolist(), strict=True)),
        gain,
        bool(at_bound and len(sigmas) * len(F_tildes) > 1),
        split,
        status,
        tuple(found),
        step,
        contiguous,
    )
