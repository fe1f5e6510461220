"""Variable projection: every surface point's albedo eliminated in closed form.

Used by the branch-and-bound over sigma (`_branch_and_bound_map.py`), by the general LM
fitter (`ctjax.fitting._map_least_squares`) and by the shading refinement
(`ctjax.sfm._shading`). For fixed nonlinear parameters (sigma) the model of a point's
observations is linear in its albedo rho and the global weights w >= 0, and each point's
albedo appears only in its own observations, so it is eliminated in closed form (Golub &
Pereyra):

    rho_pc(w) = max(0, (S_aI - sum_g w_gc S_ag) / S_aa)       S_xy = sum_m x_pm y_pm

which leaves a nonnegative least squares in the few global weights with the reduced normal
equations sum_p (S_gh - S_ag S_ah / S_aa) (and sum_p S_gh for points whose albedo is clamped
at 0). That is solved exactly (`nnls_normal_equations`); the clamped set is updated a few
times (`_ACTIVE_SET_ROUNDS`: the cost is convex in w, and a clamped albedo is rare on
tissue).
"""

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._typing import Array, Bool, Float
from ._closed_form import nnls_normal_equations

# A view is predicted only where the point's other views hold at least this share of the
# view's own information about its albedo (sum of w a^2 against the view's w a^2, a the
# diffuse shading): an albedo from views the model calls 3x dimmer or more amplifies their
# noise, and any error of the model there, as much. Measured on the shared sinus (12
# frames, 640 px, two reconstructions that differ by a few hundred pixels of mask a frame):
# with the previous bar (1e-6 of the point's information) 50 of 26k held-out views, lit
# 0.16 by the fitted light and under 0.002 in their other views, carried 99.7-99.9% of the
# squared error of three of the four falloff sets (480-1142 levels; the spot's 34.8), and
# the falloff chosen differed between the reconstructions (spot, inverse square); with
# this bar both choose inverse square (23.7 and 22.0 levels held-out).
OTHER_VIEWS_SHARE = 0.1

# Rounds of the clamped-albedo update (see the module doc).
_ACTIVE_SET_ROUNDS = 3
# A point whose diffuse column's squared norm is below this fraction of the largest carries
# no information on its albedo (grazing in every view).
_NEGLIGIBLE = 1e-12


class _Sums(NamedTuple):
    """The weighted columns and values, and the per-point sums over views the projection
    needs, one array per channel (XLA's CPU code ran the projection 1.7x slower on
    (C, M, P) arrays): `a` the per-point lobe's column (M, P), `others` the global lobes'
    (G of them), `values` C arrays (M, P), all times the root of each observation's
    weight; `s_aa` (P,), `s_ai` C arrays (P,) and `s_ag` G arrays (P,): the sums over views
    of a a, a I and a g; `t_gg` (G, G) and `t_gi` (G, C): the sums over every observation
    of g h and g I, `t_ii` (scalar) of I I over every channel too."""

    a: Array
    others: list
    values: list
    s_aa: Array
    s_ai: list
    s_ag: list
    t_gg: Array
    t_gi: Array
    t_ii: Array


def over_views(x: Float[Array, "M ..."]) -> Float[Array, "..."]:
    """The sum over the leading axis (views, or corners) as adds of contiguous slices: XLA's
    CPU code reduces a leading axis element by element (a batch of 8 sigmas x 8 views x 16k
    points: 3.4 ms as `jnp.sum(axis=0)`, 0.11 ms as adds)."""
    return functools.reduce(jnp.add, [x[m] for m in range(x.shape[0])])


def over_views_at_once(x: Float[Array, "M ..."]) -> Float[Array, "..."]:
    """The sum over the leading axis as one reduction: for one model and its forward-mode
    Jacobian (the LM fitters), where `over_views`' adds are the slow way. On a near light
    with a gain per frame (12 frames, 16384 points, 590k residuals; XLA:CPU's loop
    emitters, as the fitters compile): the Jacobian as one `jax.jacfwd` program 3.66 s with
    adds against 0.77 s, 0.49 against 0.19 s without the gains (3 parameters), the
    residuals 0.081 against 0.037 s, the same values within 1e-15
    (`benchmarks/projection_sums.py`). Inside DenseLM's loop the adds were less slow: that
    capture's `ctjax calibrate-light --effects frame_exposure` ran its LM fits 12-17%
    faster, with bitwise the same results. Under `vmap` over many nonlinear parameters
    (the branch and bound) the adds stay faster: its map fit 1.07 s against 1.71 s
    (`benchmarks/albedo_map.py`, 320x256 x 8)."""
    return jnp.sum(x, axis=0)


def weighted_sums(columns, values, weight, per_point, over=over_views) -> _Sums:
    # Double where: weights may depend on fitted parameters (undone image effects), and the
    # slope of sqrt at an unobserved slot's 0 would make their gradient NaN.
    positive = weight > 0
    w = jnp.where(positive, jnp.sqrt(jnp.where(positive, weight, 1)), 0)
    a = columns[per_point] * w
    others = [c * w for k, c in enumerate(columns) if k != per_point]
    values = [values[c] * w for c in range(values.shape[0])]
    total = lambda x, y: over(x * y)  # noqa: E731

    def every(x, y):  # (len(x), len(y)): the sums over every observation
        sums = [jnp.sum(p * q) for p in x for q in y]
        if not sums:
            return jnp.zeros((len(x), len(y)), a.dtype)
        return jnp.stack(sums).reshape(len(x), len(y))

    return _Sums(
        a,
        others,
        values,
        total(a, a),
        [total(a, v) for v in values],
        [total(a, g) for g in others],
        every(others, others),
        every(others, values),
        sum(jnp.sum(v * v) for v in values),
    )


def _global_weights(s: _Sums, inverse, ok):
    """The global weights (G, C) by the reduced NNLS, the set of albedos they clamp at 0
    updated `_ACTIVE_SET_ROUNDS` times (one round traced and looped, the channels' solves
    batched: less to trace and compile)."""
    lobes = range(len(s.others))
    solve = jax.vmap(lambda g, r: nnls_normal_equations(g, r[:, None])[:, 0], (2, 1), 1)

    def albedo_given(weights):  # (C, P)
        return jnp.stack(
            [
                (s_ai - sum(s.s_ag[g] * weights[g, c] for g in lobes)) * inverse
                for c, s_ai in enumerate(s.s_ai)
            ]
        )

    def round_(_, carry):
        free = carry[1]  # (C, P): the albedos not clamped at 0
        projected = inverse * free
        gram = jnp.stack(
            [
                jnp.stack([jnp.sum(s.s_ag[g] * s.s_ag[h] * projected, axis=-1) for h in lobes])
                for g in lobes
            ]
        )  # (G, G, C)
        s_ai = jnp.stack(s.s_ai)
        rhs = jnp.stack([jnp.sum(s.s_ag[g] * projected * s_ai, axis=-1) for g in lobes])
        weights = solve(s.t_gg[..., None] - gram, s.t_gi - rhs)
        return weights, ok & (albedo_given(weights) > 0)

    start = (
        jnp.zeros((len(s.others), len(s.values)), inverse.dtype),
        jnp.stack([ok] * len(s.values)),
    )
    return jax.lax.fori_loop(0, _ACTIVE_SET_ROUNDS, round_, start)[0]


def _project(columns, values, weight, per_point, over=over_views):
    """The sums (`_Sums`), the albedos (C arrays (P,), clamped at 0) and the global weights
    (G, C): see `project_weights`; `over`: how the sums over views are taken."""
    s = weighted_sums(columns, values, weight, per_point, over)
    ok = s.s_aa > _NEGLIGIBLE * jnp.max(s.s_aa)
    inverse = jnp.where(ok, 1 / jnp.where(ok, s.s_aa, 1), 0)
    if s.others:
        weights = _global_weights(s, inverse, ok)
    else:
        weights = jnp.zeros((0, values.shape[0]), values.dtype)
    return s, _albedo(s, inverse, ok, weights), weights


def _albedo(s: _Sums, inverse, ok, weights):
    """Each point's albedo given the global weights (G, C), clamped at 0 (C arrays (P,))."""
    return [
        jnp.where(
            ok,
            jnp.maximum((s_ai - sum(g * weights[i, c] for i, g in enumerate(s.s_ag))) * inverse, 0),
            0,
        )
        for c, s_ai in enumerate(s.s_ai)
    ]


def _residuals(s: _Sums, albedo, weights):
    """The weighted residuals the albedos and global weights leave (C arrays (M, P))."""
    return [
        v - s.a * rho - sum(g * weights[i, c] for i, g in enumerate(s.others))
        for c, (v, rho) in enumerate(zip(s.values, albedo, strict=True))
    ]


def _cost(s: _Sums, albedo, weights):
    """The sum of the squared weighted residuals. In float64 from the sums, without a
    second pass over the observations: with the albedos eliminated, a point's residuals
    are those of the global lobes alone less what its albedo explains, s_aa rho^2 (0 where
    it is clamped), so the cost is t_II - 2 w.t_gI + w^T t_gg w - sum_p s_aa rho_p^2 per
    channel (the cancellation leaves about 1e-16 of t_II: far below the differences the
    search compares). In float32 that cancellation would not be, from the residuals."""
    if s.a.dtype != jnp.float64:
        return sum(jnp.sum(r * r) for r in _residuals(s, albedo, weights))
    cost = s.t_ii
    for c, rho in enumerate(albedo):
        w = weights[:, c]
        cost = cost - 2 * (w @ s.t_gi[:, c]) + w @ s.t_gg @ w - jnp.sum(s.s_aa * rho * rho)
    return cost


def _with_per_point_row(weights, per_point: int):
    """The global weights (G, C) with the per-point lobe's row (0) inserted: (K, C)."""
    return jnp.insert(weights, per_point, jnp.zeros(weights.shape[1], weights.dtype), axis=0)


def residuals_given_weights(
    columns: tuple[Float[Array, "M P"], ...],
    values: Float[Array, "C M P"],
    weight: Float[Array, "M P"],
    weights: Float[Array, "K C"],
    per_point: int = 0,
) -> Float[Array, "C M P"]:
    """The weighted residuals with the global `weights` (K, C; row `per_point` ignored)
    given and each point's albedo eliminated: the same as `projected_residuals` at the
    weights it returns, but every point's residuals now depend on its own columns alone.
    The Jacobian of the projected residuals is this function's (local to each point) plus
    its derivative along the weights times theirs (rank (K - 1) C): see `ctjax.sfm._shading`."""
    s = weighted_sums(columns, values, weight, per_point)
    ok = s.s_aa > _NEGLIGIBLE * jnp.max(s.s_aa)
    inverse = jnp.where(ok, 1 / jnp.where(ok, s.s_aa, 1), 0)
    others = jnp.concatenate([weights[:per_point], weights[per_point + 1 :]])
    return jnp.stack(_residuals(s, _albedo(s, inverse, ok, others), others))


def projected_residuals(
    columns: tuple[Float[Array, "M P"], ...],
    values: Float[Array, "C M P"],
    weight: Float[Array, "M P"],
    per_point: int = 0,
    over=over_views,
):
    """`project_weights`, returning the weighted residuals (C, M, P) instead of their cost:
    the residual function of a least-squares solver over the nonlinear parameters alone
    (variable projection; differentiable, the clamped albedos held at 0). `over`: how the
    sums over views are taken (`over_views_at_once` for a solver's Jacobian)."""
    s, albedo, weights = _project(columns, values, weight, per_point, over)
    residual = jnp.stack(_residuals(s, albedo, weights))
    return jnp.stack(albedo, axis=-1), _with_per_point_row(weights, per_point), residual


def project_weights(
    columns: tuple[Float[Array, "M P"], ...],
    values: Float[Array, "C M P"],
    weight: Float[Array, "M P"],
    per_point: int = 0,
):
    """The albedo of every point and the global weights, eliminated in closed form.

    P points seen in up to M views each, laid out views first and points last
    (`ctjax._tracks.views_first`): `columns[k]` (M, P) is lobe k's value for unit weight at
    each observation, `values` (C, M, P) the measurements, `weight` (M, P) each
    observation's least-squares weight (0: not observed); `per_point` the lobe whose weight
    is per point (the diffuse one). Returns `(albedo (P, C), weights (K, C), cost)`:
    `weights[per_point]` is 0 (the albedo is per point), the cost is the weighted sum of
    squared residuals (finite or +inf).
    """
    s, albedo, weights = _project(columns, values, weight, per_point)
    cost = _cost(s, albedo, weights)
    full = _with_per_point_row(weights, per_point)
    return jnp.stack(albedo, axis=-1), full, jnp.where(jnp.isfinite(cost), cost, jnp.inf)


def albedo_from_other_views(
    a: Float[Array, "M P"],
    target: Float[Array, "C M P"],
    weight: Float[Array, "M P"],
    judged: Bool[Array, "M P"],
) -> tuple[Float[Array, "C M P"], Bool[Array, "M P"]]:
    """Each view's albedo from its point's OTHER views (leave one out): per channel, the
    least-squares albedo of `target` (the values less the global lobes) on the per-point
    column `a` over the point's views but that one, clamped at 0; and where it is usable
    (`judged`, observed, and the other views holding at least `OTHER_VIEWS_SHARE` of the
    view's own information). A held-out view's prediction (`ctjax.fitting`'s held-out RMSE)
    and a frame's brightness against the others' (`fit`'s check)."""
    s_aa = jnp.sum(weight * a * a, axis=0)  # (P,)
    s_ai = jnp.sum(weight * a * target, axis=1, keepdims=True)  # (C, 1, P)
    others = s_aa - weight * a * a  # (M, P): the other views' normal equations
    other_ai = s_ai - weight * a * target
    ok = judged & (weight > 0) & (others >= OTHER_VIEWS_SHARE * weight * a * a) & (others > 0)
    return jnp.maximum(other_ai / jnp.where(ok, others, 1), 0), ok
