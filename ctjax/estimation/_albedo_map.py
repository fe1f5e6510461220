"""The BRDF with an albedo map: rho_tilde per surface point and channel, F_tilde and sigma
shared, from all frames (beyond the paper, whose eq. 1 has one rho_tilde per capture).

Real tissue is textured, and a texture is indistinguishable from N.L in one frame; not
across frames, since the light moves with the camera (see `ctjax._tracks`). The unknowns:
one albedo per surface point p and channel c, the global linear weights g (F_tilde, or
several specular weights) and the nonlinear parameters (sigma). The model of observation m of
point p is

    I_pmc = rho_pc a_pm + sum_g w_gc b_gpm(sigma)                   a: the diffuse column

For fixed sigma it is linear in (rho, w) >= 0, and each point's albedo appears only in its
own observations, so it is eliminated in closed form (variable projection, Golub & Pereyra):

    rho_pc(w) = max(0, (S_aI - sum_g w_gc S_ag) / S_aa)       S_xy = sum_m x_pm y_pm

which leaves a nonnegative least squares in the few global weights with the reduced normal
equations sum_p (S_gh - S_ag S_ah / S_aa) (and sum_p S_gh for points whose albedo is clamped
at 0). That is solved exactly (`nnls_normal_equations`); the clamped set is updated a few
times (`_ACTIVE_SET_ROUNDS`: the cost is convex in w, and a clamped albedo is rare on
tissue). The sigma branch-and-bound is then the same batched grid of closed-form solves as the
paper's, with 10^5 albedos eliminated instead of searched.

A point observed once has its albedo fitted exactly (no residual): it tells nothing about
sigma and w, and counts for nothing in their fit. Given the fit, its albedo is still
determined by its one observation (see `albedo_maps`).
"""

import functools
import itertools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._buckets import bucket
from .._errors import CtjaxError
from .._numerics import safe_normalize
from .._programs import persistent_jit
from .._render import render_columns
from .._tracks import (
    DEFAULT_NEIGHBOURS,
    DEFAULT_TOLERANCE,
    FrameData,
    Tracks,
    partners,
    sample_image,
    sight,
    sight_own,
    world_points,
)
from .._typing import Array, Bool, Float, Scalar
from .._vector import Vec3
from ..lights import AbstractLight, ColocatedLight
from ..observations import ShadingSamples
from ._branch_and_bound import grid_search
from ._brdf import PAPER, BRDFFamily, design_geometry
from ._closed_form import nnls_normal_equations

# Rounds of the clamped-albedo update (see the module doc).
_ACTIVE_SET_ROUNDS = 3
# A point whose diffuse column's squared norm is below this fraction of the largest carries
# no information on its albedo (grazing in every view).
_NEGLIGIBLE = 1e-12
# Albedo maps are left NaN where the diffuse column is below this (N.L / pi in every view
# below ~0.05 / pi): the albedo would be noise divided by nearly 0.
MIN_COSINE = 0.05
# Pixels whose albedo is estimated at once (bounds memory at 1080p).
_MAP_CHUNK = 1 << 17
# Grid points evaluated at once by the BnB (each a pass over every observation's corners):
# one, measured: 80 evaluations on 16k tracks x 8 views took 0.11 s one at a time, 0.22 s
# two at a time and 0.29 s eight at a time (XLA's CPU code reduces the leading axes of the
# batched (sigmas, views, points) arrays element by element).
_GRID_BATCH = 1
# The BnB's first `_COARSE_LEVELS` levels evaluate every `_COARSE_STEP`-th track (`_fit`).
_COARSE_STEP = 4
_COARSE_LEVELS = 2
# The paper's light: at the camera centre, L = V.
_PAPER_LIGHT = ColocatedLight()


class TrackShading(eqx.Module):
    """Tracks as the BnB sees them, views first and points last (`views_first`: per-point
    sums over views are then sums of contiguous rows): the shading samples of every
    observation's four corners, flattened (4 M P), the corners' bilinear weights (4, M, P),
    the measured RGB (3, M, P) and each observation's least-squares weight (M, P;
    0: not observed)."""

    samples: ShadingSamples
    corner_weight: Float[Array, "4 M P"]
    values: Float[Array, "C M P"]
    weight: Float[Array, "M P"]

    @property
    def shape(self) -> tuple[int, int]:
        """(M, P): views per point, points."""
        return self.weight.shape

    @property
    def observed(self) -> Bool[Array, "M P"]:
        return self.weight > 0

    def every(self, step: int) -> "TrackShading":
        """Every `step`-th point (an unbiased subset: tracks are ordered by anchor frame)."""
        m, p = self.shape

        def flat(leaf):  # flattened corners (4 M P, ...)
            return leaf.reshape(4, m, p, *leaf.shape[1:])[:, :, ::step].reshape(-1, *leaf.shape[1:])

        return TrackShading(
            jax.tree.map(flat, self.samples),
            self.corner_weight[..., ::step],
            self.values[..., ::step],
            self.weight[..., ::step],
        )


def _shade(light: AbstractLight, point: Vec3, normal: Vec3, pixel):
    view = safe_normalize(-point)
    direction, irradiance = light.illuminate(point, view, pixel)
    return normal, direction, view, irradiance


def _views_first(array):
    """`ctjax._tracks.views_first` traced (XLA fuses the transposition into its consumers:
    in NumPy it was 40% of the tracks' shading)."""
    if array.ndim == 2:
        return array.T
    moved = jnp.moveaxis(array, (0, 2), (2, 0))
    return moved if array.ndim == 3 else moved.reshape(-1, array.shape[-1])


@persistent_jit
def _track_shading(light, point, normal, pixel, corner_weight, values, weight) -> TrackShading:
    # Compiled (and kept between processes): op by op, a new process spent 0.2 s lowering
    # each operation of the light's model.
    point, normal, pixel = (_views_first(a) for a in (point, normal, pixel))
    n, l, v, e = jax.vmap(lambda p, q, x: _shade(light, p, q, x))(
        Vec3.from_array(point), Vec3.from_array(normal), (pixel[:, 0], pixel[:, 1])
    )
    samples = ShadingSamples(n, l, v, e, jnp.zeros((len(point), 3), point.dtype))
    return TrackShading(
        samples, _views_first(corner_weight), _views_first(values), _views_first(weight)
    )


def track_shading(tracks: Tracks, light: AbstractLight = _PAPER_LIGHT, dtype=None):
    """`tracks` under `light` (the paper's, L = V, by default) as `TrackShading`."""
    dtype = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
    as_host = lambda a: np.asarray(a, dtype)  # noqa: E731
    return _track_shading(
        light,
        *(
            as_host(a)
            for a in (
                tracks.corner_point,
                tracks.corner_normal,
                tracks.corner_pixel,
                tracks.corner_weight,
                tracks.values,
                tracks.weight,
            )
        ),
    )


def _per_point_index(family: BRDFFamily) -> int:
    if "rho_tilde" not in family.weight_names:
        raise CtjaxError(f"BRDF family {family.names} has no rho_tilde weight to map")
    return family.weight_names.index("rho_tilde")


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


def _over_views(x: Float[Array, "M ..."]) -> Float[Array, "..."]:
    """The sum over the leading axis (views, or corners) as adds of contiguous slices: XLA's
    CPU code reduces a leading axis element by element (a batch of 8 sigmas x 8 views x 16k
    points: 3.4 ms as `jnp.sum(axis=0)`, 0.11 ms as adds)."""
    return functools.reduce(jnp.add, [x[m] for m in range(x.shape[0])])


def _sums(columns, values, weight, per_point) -> _Sums:
    # Double where: weights may depend on fitted parameters (undone image effects), and the
    # slope of sqrt at an unobserved slot's 0 would make their gradient NaN.
    positive = weight > 0
    w = jnp.where(positive, jnp.sqrt(jnp.where(positive, weight, 1)), 0)
    a = columns[per_point] * w
    others = [c * w for k, c in enumerate(columns) if k != per_point]
    values = [values[c] * w for c in range(values.shape[0])]
    total = lambda x, y: _over_views(x * y)  # noqa: E731

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


def _project(columns, values, weight, per_point):
    """The sums (`_Sums`), the albedos (C arrays (P,), clamped at 0) and the global weights
    (G, C): see `project_weights`."""
    s = _sums(columns, values, weight, per_point)
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
    s = _sums(columns, values, weight, per_point)
    ok = s.s_aa > _NEGLIGIBLE * jnp.max(s.s_aa)
    inverse = jnp.where(ok, 1 / jnp.where(ok, s.s_aa, 1), 0)
    others = jnp.concatenate([weights[:per_point], weights[per_point + 1 :]])
    return jnp.stack(_residuals(s, _albedo(s, inverse, ok, others), others))


def projected_residuals(
    columns: tuple[Float[Array, "M P"], ...],
    values: Float[Array, "C M P"],
    weight: Float[Array, "M P"],
    per_point: int = 0,
):
    """`project_weights`, returning the weighted residuals (C, M, P) instead of their cost:
    the residual function of a least-squares solver over the nonlinear parameters alone
    (variable projection; differentiable, the clamped albedos held at 0)."""
    s, albedo, weights = _project(columns, values, weight, per_point)
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


def _corner_geometry(family, shading: TrackShading):
    """What the columns take of the tracks whatever the nonlinear parameters (computed once
    for the BnB): each lobe's `geometry` at every observation's corners (flattened 4 M P),
    and the corners' bilinear weights times the irradiance (4, M, P)."""
    corners = shading.corner_weight
    irradiance = shading.samples.irradiance.reshape(corners.shape)
    return design_geometry(family, shading.samples), corners * irradiance


def _columns(family, params, shading: TrackShading, corners=None):
    """Each lobe's value for unit weight at every observation (M, P): at the corners,
    bilinearly combined like the image. `corners`: `_corner_geometry(family, shading)`
    (computed here otherwise)."""
    geometry, factor = _corner_geometry(family, shading) if corners is None else corners
    return tuple(
        _over_views(c.reshape(factor.shape) * factor)  # the four corners: leading axis
        for c in jax.vmap(family.build(params).columns_given)(geometry)
    )


def _values(shading: TrackShading):
    return shading.values


class AlbedoMapFit(eqx.Module):
    """The estimate with an albedo map: nonlinear `params` (D,), global `weights` (K, 3)
    whose per-point row holds the albedos' median, the albedo of every track (P, 3), the
    cost (sum of squared residuals, linear units) and RMSE (8-bit levels) over the observed
    slots, the standard errors of the global parameters (the per-point row: NaN)."""

    params: Float[Array, " D"]
    weights: Float[Array, "K 3"]
    albedo: Float[Array, "P 3"]
    cost: Scalar
    rgb_rmse: Scalar
    params_stderr: Float[Array, " D"]
    weights_stderr: Float[Array, "K 3"]
    search_half_width: Float[Array, " D"]
    n_samples: int = eqx.field(static=True)
    family: BRDFFamily = eqx.field(static=True)

    @property
    def brdf(self):
        # Built from host values: eager JAX ops would each compile a program.
        return self.family.build(np.asarray(self.params)).with_weights(np.asarray(self.weights))


def _information(family, params, weights, albedo, shading, per_point, cost):
    """The Gauss-Newton information matrix of the global parameters (the global weights,
    channel fastest, then the nonlinear parameters) with every albedo eliminated, and the
    residual variance: from the Jacobian of the projected residuals (the albedos' clamped
    set held fixed), whose Gauss-Newton covariance is the global block of the joint one (a
    Schur complement). Inverted on the host (`_standard_errors`).

    The residual of channel c is linear in the global weights w_gc given the columns:
    r_c = v_c - a rho_c - sum_g g w_gc with rho_c = (s_aIc - sum_g s_ag w_gc) / s_aa, so
    d r_c / d w_gc = a s_ag / s_aa - g (0 for a clamped albedo, and in the other channels).
    Only the nonlinear parameters are differentiated by autodiff (`jax.jacfwd`): a forward
    pass per parameter instead of one per weight and channel.
    """
    k, channels = weights.shape
    free = albedo.T > 0  # (C, P)
    globals_ = [i for i in range(k) if i != per_point]
    n_weights, dims = len(globals_) * channels, params.shape[0]
    n_observed = jnp.sum(shading.observed) * channels
    scale = cost / jnp.maximum(n_observed - (n_weights + dims + jnp.sum(free)), 1)
    if n_weights + dims == 0:  # every weight is per point: nothing global
        return jnp.zeros((0, 0), weights.dtype), scale
    w = weights[jnp.array(globals_, int)]  # (G, C)

    def sums(p):
        s = _sums(_columns(family, p, shading), shading.values, shading.weight, per_point)
        inverse = jnp.where(s.s_aa > 0, 1 / jnp.where(s.s_aa > 0, s.s_aa, 1), 0)
        return s, [jnp.where(f, inverse, 0) for f in free]

    def residuals(p):  # (C, M, P)
        s, inverse = sums(p)
        return jnp.stack(
            [
                v
                - s.a * (s_ai - sum(ag * w[g, c] for g, ag in enumerate(s.s_ag))) * inverse[c]
                - sum(g * w[i, c] for i, g in enumerate(s.others))
                for c, (v, s_ai) in enumerate(zip(s.values, s.s_ai, strict=True))
            ]
        )

    s, inverse = sums(params)
    by_param = jnp.moveaxis(jax.jacfwd(residuals)(params), -1, 0)  # (D, C, M, P)
    # The Jacobian's columns in the parameters' order, each as {channel: (M, P)} (a weight's
    # column is 0 in the other channels).
    jacobian = [
        {c: s.a * (s.s_ag[g] * inverse[c]) - s.others[g]}
        for g in range(len(globals_))
        for c in range(channels)
    ] + [{c: by_param[d, c] for c in range(channels)} for d in range(dims)]
    entry = {}
    for i, x in enumerate(jacobian):
        for j, y in enumerate(jacobian[i:], start=i):
            shared = sorted(x.keys() & y.keys())
            total = sum((jnp.sum(x[c] * y[c]) for c in shared), jnp.zeros((), weights.dtype))
            entry[i, j] = entry[j, i] = total
    size = len(jacobian)
    information = jnp.stack([jnp.stack([entry[i, j] for j in range(size)]) for i in range(size)])
    return information, scale


def _standard_errors(information, scale, weight_names, per_point: int, channels: int):
    """The standard errors of the nonlinear parameters (D,) and of the global weights (K, C;
    NaN in the per-point row) from `_information`, in NumPy: a matrix this small is not
    worth LAPACK kernels in the compiled program."""
    information, scale = np.asarray(information), np.asarray(scale)
    n, k = information.shape[0], len(weight_names)
    n_weights = (k - 1) * channels
    weights_stderr = np.full((k, channels), np.nan, information.dtype)
    if n == 0:
        return np.zeros(0, information.dtype), weights_stderr
    # jnp.linalg's default tolerances, in the information's own precision.
    rtol = 10 * n * np.finfo(information.dtype).eps
    covariance = scale * np.linalg.pinv(information, rcond=rtol, hermitian=True)
    variance = np.diagonal(covariance)
    rank_deficient = np.linalg.matrix_rank(information, hermitian=True) < n
    stderr = np.where(rank_deficient | (variance < 0), np.inf, np.sqrt(np.abs(variance)))
    globals_ = [i for i in range(k) if i != per_point]
    weights_stderr[globals_] = stderr[:n_weights].reshape(len(globals_), channels)
    return stderr[n_weights:], weights_stderr


@persistent_jit
def _fit(shading, family, per_point, tolerance, grid, candidates, zoom, zoom_grid):
    values, weight, observed = _values(shading), shading.weight, shading.observed

    # What the columns take of the tracks whatever sigma: computed once, not per evaluation.
    corners = _corner_geometry(family, shading)

    def cost(params, shading=shading, corners=corners):
        columns = _columns(family, params, shading, corners)
        return project_weights(columns, shading.values, shading.weight, per_point)[2]

    dtype = values.dtype
    # The first level only picks the boxes the later ones narrow (`grid_search`): on every
    # `_COARSE_STEP`-th track it finds the same ones at a fraction of the cost.
    coarse = shading.every(_COARSE_STEP)
    coarse_corners = _corner_geometry(family, coarse)
    if family.names:
        found = grid_search(
            cost,
            family.lo,
            family.hi,
            tolerance=tolerance,
            grid=grid,
            candidates=candidates,
            zoom=zoom,
            zoom_grid=zoom_grid,
            dtype=dtype,
            batch=_GRID_BATCH,
            coarse=lambda params: cost(params, coarse, coarse_corners),
            coarse_levels=_COARSE_LEVELS,
        )
        params, half_width = found.params, found.half_width
    else:
        params = jnp.zeros((0,), dtype)
        half_width = params
    columns = _columns(family, params, shading, corners)
    albedo, weights, best = project_weights(columns, values, weight, per_point)
    information = _information(family, params, weights, albedo, shading, per_point, best)
    # The RMSE of every observation, unweighted: what a user compares with the noise.
    model = sum(
        c * (albedo.T[:, None, :] if k == per_point else weights[k][:, None, None])
        for k, c in enumerate(columns)
    )
    residual = jnp.where(observed, values - model, 0)
    counted = jnp.sum(observed) * values.shape[0]
    rmse = 255 * jnp.sqrt(jnp.sum(residual * residual) / jnp.maximum(counted, 1))
    return params, weights, albedo, best, rmse, information, half_width


def _padded_points(shading: TrackShading) -> TrackShading:
    """`shading` with its points padded to a bucket size (`ctjax._buckets`), the padding
    unobserved (weight 0; the samples repeat the last point's, finite): captures of similar
    size share the BnB's compiled program."""
    m, p = shading.shape
    size = bucket(p)
    if size == p:
        return shading

    def repeat_last(leaf):  # flattened corners (4 M P, ...): the point axis is third
        host = np.asarray(leaf)
        shaped = host.reshape(4, m, p, *host.shape[1:])
        tail = np.repeat(shaped[:, :, -1:], size - p, axis=2)
        return jnp.asarray(np.concatenate([shaped, tail], axis=2).reshape(-1, *host.shape[1:]))

    def zeros(leaf):  # (..., M, P): the point axis is last
        host = np.asarray(leaf)
        return jnp.asarray(np.pad(host, [(0, 0)] * (host.ndim - 1) + [(0, size - p)]))

    return TrackShading(
        jax.tree.map(repeat_last, shading.samples),
        zeros(shading.corner_weight),
        zeros(shading.values),
        zeros(shading.weight),
    )


def fit_brdf_map(
    shading: TrackShading,
    family: BRDFFamily = PAPER,
    *,
    tolerance: float = 1e-3,
    grid: int = 32,
    candidates: int = 2,
    zoom: int = 2,
    zoom_grid: int = 8,
) -> AlbedoMapFit:
    """The BRDF with one albedo per tracked point (see the module doc): the sigma BnB over
    closed-form solves in which every albedo and the global weights are eliminated.
    `grid` points per axis at the first level, `zoom_grid` at the later ones, `candidates`
    boxes kept per level (see `grid_search`): each cost evaluation passes over every
    observation, and 8 points in 2 boxes reach the same tolerance as 32 in 4 in 80
    evaluations instead of 128 (the same sigma on every capture tried; the first level's 32
    points find the basins).

    The global weights' per-point row (`rho_tilde`) reports the median albedo per channel.
    """
    # (NumPy here: an eager JAX op compiles a program, milliseconds each in a new process.)
    observed = np.asarray(shading.weight) > 0
    views = observed.sum(axis=0)
    k = len(family.weight_names)
    informative = int(np.sum(views[views > 1] - 1))
    if informative < 3 * (k - 1) + len(family.names) + 1:
        raise CtjaxError(
            f"{len(views)} tracked points with {int(observed.sum())} observations: too few "
            "points seen in two frames or more to separate the albedo from the BRDF (poses "
            "or depth wrong, or frames that do not overlap?)"
        )
    values = np.asarray(shading.values)[:, observed]
    if not np.all(np.isfinite(values)):
        raise CtjaxError("observed values contain NaN or inf")
    per_point = _per_point_index(family)
    params, weights, albedo, cost, rmse, information, half = _fit(
        _padded_points(shading),
        family,
        per_point,
        tolerance,
        grid,
        candidates,
        zoom,
        zoom_grid,
    )
    if albedo.shape[0] != len(views):  # padded by `_padded_points`
        albedo = albedo[: len(views)]
    seen = views > 1
    median = np.median(np.asarray(albedo)[seen], axis=0) if seen.any() else np.zeros(3)
    weights = np.array(weights)
    weights[per_point] = median
    weights = jax.device_put(weights)
    errors = _standard_errors(*information, family.weight_names, per_point, weights.shape[1])
    p_err, w_err = map(jax.device_put, errors)
    return AlbedoMapFit(
        params, weights, albedo, cost, rmse, p_err, w_err, half, int(observed.sum()), family
    )


@persistent_jit
def _frame_columns(brdf, light, camera, normals, depth):
    """One frame's lobes for unit weights at its pixel centres, (H, W, K) float32 (0 where
    it has no geometry): K planes per pixel, the least a frame's model can be kept in."""
    return render_columns(brdf, light, camera, normals, depth).astype(jnp.float32)


def _albedo_of(capture, data, shading, weights, per_point, pieces, count, among, tolerance):
    """Albedo (N, 3; NaN where not estimated) and view count (N,) of the pixels of
    `pieces`, [(frame index, rows, cols)], from all the frames that see them (see
    `albedo_maps`), and each pixel's residual in its own frame (N, 3) under the albedo of
    the other views alone (NaN where they have none); N pixels in all, in the pieces' order.
    `shading(f)` is frame f's `_frame_columns`: a point's model in another view is their
    bilinear sample, as its value is the image's. Each frame is sighted once for every
    piece that looks for its points there (a summary's few thousand pixels per frame were
    mostly NumPy's per-call overhead when sighted frame by frame)."""
    camera = capture.camera
    bounds = np.cumsum([0, *(len(rows) for _, rows, _ in pieces)])
    n = int(bounds[-1])
    world = np.concatenate(
        [world_points(camera, capture.frames[i], rows, cols) for i, rows, cols in pieces]
    )
    numerator, denominator = np.zeros((n, 3)), np.zeros((n, 3))
    cosine, seen_count = np.zeros(n), np.zeros(n, int)
    own = [np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))]
    global_ = np.arange(len(weights)) != per_point
    looked = [partners(capture, i, count, among) for i, _, _ in pieces]

    def add(where, obs, columns):  # one frame's observations of the pixels `where`
        seen = obs.weight > 0  # some channel counts
        columns = np.where(seen[:, None], columns.reshape(len(seen), -1), 0.0)  # (N, K)
        a, rest = columns[:, per_point], columns[:, global_] @ weights[global_]
        # Per channel: a channel clipped in this view says nothing of that channel's albedo.
        weight = obs.weight[:, None] * obs.channel_seen
        contribution = a[:, None] * (obs.values - rest) * weight
        numerator[where] += contribution
        denominator[where] += (a * a)[:, None] * weight
        cosine[where] += a * a * seen
        seen_count[where] += seen
        return a, rest, obs.values, weight, contribution

    for other in dict.fromkeys(f for frames in looked for f in frames):
        away = []
        for (index, rows, cols), frames, lo, hi in zip(
            pieces, looked, bounds[:-1], bounds[1:], strict=True
        ):
            if index == other:
                part = slice(lo, hi)
                found = add(part, sight_own(data[index], rows, cols), shading(other)[rows, cols])
                for kept, value in zip(own, found, strict=True):
                    kept[part] = value
            elif other in frames:
                away.append((lo, hi))
        if away:
            # A slice where the pieces are contiguous (one frame's pixels: a dense map).
            contiguous = all(a[1] == b[0] for a, b in itertools.pairwise(away))
            where = (
                slice(away[0][0], away[-1][1])
                if contiguous
                else np.concatenate([np.arange(lo, hi) for lo, hi in away])
            )
            obs = sight(camera, data[other], world[where], tolerance)
            add(where, obs, sample_image(shading(other), obs.u, obs.v))
    enough = (cosine[:, None] > (MIN_COSINE / np.pi) ** 2) & (denominator > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        albedo = np.where(enough, np.maximum(numerator / denominator, 0), np.nan)
        # The own observation against the albedo of the other views alone.
        a, rest, values, weight, own_numerator = own
        others = denominator - (a * a)[:, None] * weight
        enough_others = enough & (others > 1e-3 * denominator)
        albedo_others = np.maximum((numerator - own_numerator) / others, 0)
        residual = values - rest - a[:, None] * albedo_others
        residual = np.where(enough_others & (weight > 0), residual, np.nan)
    return albedo, seen_count, residual


def albedo_maps(
    capture,
    brdf,
    light: AbstractLight = _PAPER_LIGHT,
    *,
    per_point: int = 0,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
    tolerance: float | None = None,
    frames=None,
    among=None,
    dtype=None,
):
    """The albedo map of every frame (of `frames`, all by default) given the fitted BRDF's
    global lobes and the light: a list of (H, W, 3) float32 maps (rho_tilde per pixel, in
    the units of `rho_tilde`, NaN where not estimated), and of (H, W) view counts.

    Every pixel with depth and a normal is followed into the frames that see it (its
    `neighbours` nearest, all when None; see `ctjax._tracks`); its albedo is the weighted
    least-squares one over those observations with the global lobes subtracted, clamped at
    0, per channel: an observation counts for the channels it has not clipped. NaN in a
    channel where no observation counts for it (clipped there in its own frame and in every
    other that sees it), and in all three where the point is grazing in every view (N.L
    below `MIN_COSINE`). A point seen in one frame only gets the albedo of that one
    observation, given the fitted BRDF. `among`: the frames a point is looked for in (all
    by default; e.g. the calibration frames alone, so that held-out frames stay unseen).
    """
    camera = capture.camera
    maps, views = [], []
    for _, rows, cols, albedo, seen_count, _ in _frames_of(
        capture, brdf, light, frames, per_point, neighbours, tolerance, dtype, among
    ):
        full = np.full((camera.height, camera.width, 3), np.nan, np.float32)
        full[rows, cols] = albedo
        count_map = np.zeros((camera.height, camera.width), np.uint16)
        count_map[rows, cols] = np.where(np.any(np.isfinite(albedo), -1), seen_count, 0)
        maps.append(full)
        views.append(count_map)
    return maps, views


def albedo_samples(
    capture,
    brdf,
    light: AbstractLight = _PAPER_LIGHT,
    *,
    stride: int,
    per_point: int = 0,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
    dtype=None,
):
    """`albedo_maps` at every frame's pixels with geometry on every `stride`-th row and
    column: per frame, their albedo (N, 3; NaN where not estimated) and view count (N,).
    A summary of the maps (median, coverage) at 1 / stride^2 of their cost."""
    return [
        (albedo, seen_count)
        for _, _, _, albedo, seen_count, _ in _frames_of(
            capture, brdf, light, None, per_point, neighbours, None, dtype, stride=stride
        )
    ]


def _frames_of(
    capture, brdf, light, frames, per_point, neighbours, tolerance, dtype, among=None, stride=1
):
    """For each frame of `frames` (all when None): its pixels with geometry (rows, cols;
    on every `stride`-th row and column) and their albedo, view count and own residual
    (`_albedo_of`), in batches of at most `_MAP_CHUNK` pixels (bounded memory at 1080p;
    several frames' at once where they are few, as a summary's)."""
    dtype = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
    tolerance = DEFAULT_TOLERANCE if tolerance is None else tolerance
    camera = capture.camera
    data = [FrameData.of(f) for f in capture.frames]
    available = len(capture) if among is None else len(among)
    count = available - 1 if neighbours is None else min(neighbours, available - 1)
    chunk = min(_MAP_CHUNK, camera.width * camera.height)

    # Each frame's lobes are rendered once and kept while its neighbours need them (frames
    # in video order share most of their neighbours): K float32 planes, 33 MB per 1080p
    # frame for the paper's model.
    @functools.lru_cache(maxsize=count + 2)
    def shading(other):
        frame = capture.frames[other]
        as_host = lambda a: np.asarray(a, dtype)  # noqa: E731
        columns = _frame_columns(brdf, light, camera, as_host(frame.normals), as_host(frame.depth))
        return np.asarray(columns)

    weights = np.stack([np.asarray(lobe.weight, np.float64) for lobe in brdf.lobes])
    pixels = {}  # every frame's (rows, cols)
    for index in range(len(capture)) if frames is None else frames:
        mask = capture.frames[index].geometry_mask
        if stride > 1:  # (every pixel of a frame whose geometry misses the grid)
            grid = (np.arange(mask.shape[0]) % stride == 0)[:, None]
            grid = grid & (np.arange(mask.shape[1]) % stride == 0)[None, :]
            mask = mask & grid if np.any(mask & grid) else mask
        pixels[index] = np.nonzero(mask)
    # Pieces of at most `chunk` pixels (a frame's, or part of one), in frame order.
    pieces = [
        (index, rows[start : start + chunk], cols[start : start + chunk])
        for index, (rows, cols) in pixels.items()
        for start in range(0, len(rows), chunk)
    ]
    parts = {index: [] for index in pixels}

    def finished(index):
        joined = [np.concatenate(x) for x in zip(*parts.pop(index), strict=True)]
        empty = [np.zeros((0, 3)), np.zeros(0, int), np.zeros((0, 3))]
        return index, *pixels[index], *(joined or empty)

    waiting = list(pixels)  # frames not yielded yet, in order
    for batch in _batched(pieces, chunk):
        out = _albedo_of(capture, data, shading, weights, per_point, batch, count, among, tolerance)
        bounds = np.cumsum([0, *(len(rows) for _, rows, _ in batch)])
        for (index, _, _), lo, hi in zip(batch, bounds[:-1], bounds[1:], strict=True):
            parts[index].append(tuple(x[lo:hi] for x in out))
        # The frames before the batch's last one are complete.
        while waiting[0] != batch[-1][0]:
            yield finished(waiting.pop(0))
    while waiting:
        yield finished(waiting.pop(0))


def _batched(pieces, chunk: int):
    """Consecutive `pieces` grouped into batches of at most `chunk` pixels in all."""
    batch, size = [], 0
    for piece in pieces:
        if batch and size + len(piece[1]) > chunk:
            yield batch
            batch, size = [], 0
        batch.append(piece)
        size += len(piece[1])
    if batch:
        yield batch


def map_residuals(
    capture,
    brdf,
    light: AbstractLight = _PAPER_LIGHT,
    frames=None,
    *,
    per_point: int = 0,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
    dtype=None,
):
    """Residual images (H, W, 3; linear units, NaN where not usable) of `frames` (all by
    default) under the albedo map, each pixel against the albedo fitted to the OTHER frames
    that see it (`albedo_maps` without its own view): its own noise is then not partly
    fitted away (which made the noise floor 14% low), and the other views' noise, averaged
    and interpolated, adds little. NaN where no other view counts."""
    camera = capture.camera
    out = []
    for _, rows, cols, _, _, residual in _frames_of(
        capture, brdf, light, frames, per_point, neighbours, None, dtype
    ):
        image = np.full((camera.height, camera.width, 3), np.nan)
        image[rows, cols] = residual
        out.append(image)
    return out
