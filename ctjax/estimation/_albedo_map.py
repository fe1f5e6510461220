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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._buckets import bucket, pad_leading
from .._errors import CtjaxError
from .._numerics import safe_normalize
from .._tracks import (
    DEFAULT_NEIGHBOURS,
    DEFAULT_TOLERANCE,
    FrameData,
    Tracks,
    observe,
    observe_own,
    partners,
    world_points,
)
from .._typing import Array, Bool, Float, Scalar
from .._vector import Vec3
from ..lights import AbstractLight, ColocatedLight
from ..observations import ShadingSamples
from ._branch_and_bound import grid_search
from ._brdf import PAPER, BRDFFamily, design_columns
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
# Grid points evaluated at once by the BnB: each is a pass over every observation's corners.
_GRID_BATCH = 4
# The paper's light: at the camera centre, L = V.
_PAPER_LIGHT = ColocatedLight()


class TrackShading(eqx.Module):
    """Tracks as the BnB sees them: the shading samples of every observation's four corners,
    flattened (P * M * 4), the corners' bilinear weights (P, M, 4), the measured RGB
    (P, M, 3) and each observation's least-squares weight (P, M; 0: not observed)."""

    samples: ShadingSamples
    corner_weight: Float[Array, "P M 4"]
    values: Float[Array, "P M 3"]
    weight: Float[Array, "P M"]

    @property
    def shape(self) -> tuple[int, int]:
        return self.weight.shape

    @property
    def observed(self) -> Bool[Array, "P M"]:
        return self.weight > 0


def _shade(light: AbstractLight, point: Vec3, normal: Vec3, pixel):
    view = safe_normalize(-point)
    direction, irradiance = light.illuminate(point, view, pixel)
    return normal, direction, view, irradiance


def _shading_samples(light, point, normal, pixel, dtype) -> ShadingSamples:
    """Shading samples under `light` of points, normals (N, 3) and pixels (N, 2)."""
    as_jax = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    n, l, v, e = jax.vmap(lambda p, q, x: _shade(light, p, q, x))(
        Vec3.from_array(as_jax(point)),
        Vec3.from_array(as_jax(normal)),
        (as_jax(pixel[:, 0]), as_jax(pixel[:, 1])),
    )
    return ShadingSamples(n, l, v, e, jnp.zeros((len(point), 3), dtype))


def track_shading(tracks: Tracks, light: AbstractLight = _PAPER_LIGHT, dtype=None):
    """`tracks` under `light` (the paper's, L = V, by default) as `TrackShading`."""
    dtype = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
    flat = lambda a: a.reshape(-1, a.shape[-1])  # noqa: E731
    samples = _shading_samples(
        light,
        flat(tracks.corner_point),
        flat(tracks.corner_normal),
        flat(tracks.corner_pixel),
        dtype,
    )
    return TrackShading(
        samples,
        jnp.asarray(tracks.corner_weight, dtype),
        jnp.asarray(tracks.values, dtype),
        jnp.asarray(tracks.weight, dtype),
    )


def _per_point_index(family: BRDFFamily) -> int:
    if "rho_tilde" not in family.weight_names:
        raise CtjaxError(f"BRDF family {family.names} has no rho_tilde weight to map")
    return family.weight_names.index("rho_tilde")


def _sums(columns, values, weight, per_point):
    """The per-point sums of products the projection needs, each observation weighted."""
    # Double where: weights may depend on fitted parameters (undone image effects), and the
    # slope of sqrt at an unobserved slot's 0 would make their gradient NaN.
    positive = weight > 0
    w = jnp.where(positive, jnp.sqrt(jnp.where(positive, weight, 1)), 0)
    a = columns[per_point] * w
    others = [c * w for k, c in enumerate(columns) if k != per_point]
    values = values * w[..., None]
    s_aa = jnp.sum(a * a, axis=1)  # (P,)
    s_ai = jnp.einsum("pm,pmc->pc", a, values)  # (P, C)
    s_ag = jnp.stack([jnp.sum(a * g, axis=1) for g in others]) if others else None  # (G, P)
    s_gh = (
        jnp.stack([jnp.stack([jnp.sum(g * h, axis=1) for h in others]) for g in others])
        if others
        else None
    )  # (G, G, P)
    s_gi = jnp.stack([jnp.einsum("pm,pmc->pc", g, values) for g in others]) if others else None
    return a, others, values, s_aa, s_ai, s_ag, s_gh, s_gi


def projected_residuals(
    columns: tuple[Float[Array, "P M"], ...],
    values: Float[Array, "P M C"],
    weight: Float[Array, "P M"],
    per_point: int = 0,
):
    """`project_weights`, returning the weighted residuals (P, M, C) instead of their cost:
    the residual function of a least-squares solver over the nonlinear parameters alone
    (variable projection; differentiable, the clamped albedos held at 0)."""
    a, others, masked, s_aa, s_ai, s_ag, s_gh, s_gi = _sums(columns, values, weight, per_point)
    ok = s_aa > _NEGLIGIBLE * jnp.max(s_aa)
    inverse = jnp.where(ok, 1 / jnp.where(ok, s_aa, 1), 0)
    free = jnp.broadcast_to(ok[:, None], s_ai.shape)
    channels = values.shape[-1]
    if others:
        solve = jax.vmap(lambda g, r: nnls_normal_equations(g, r[:, None])[:, 0], (2, 1), 1)
        weights = jnp.zeros((len(others), channels), values.dtype)
        for _ in range(_ACTIVE_SET_ROUNDS):
            projected = inverse[:, None] * free  # (P, C)
            gram = jnp.sum(s_gh, axis=-1)[..., None] - jnp.einsum(
                "gp,hp,pc->ghc", s_ag, s_ag, projected
            )
            rhs = jnp.sum(s_gi, axis=1) - jnp.einsum("gp,pc->gc", s_ag, projected * s_ai)
            weights = solve(gram, rhs)
            albedo = (s_ai - jnp.einsum("gp,gc->pc", s_ag, weights)) * inverse[:, None]
            free = ok[:, None] & (albedo > 0)
        rest = sum(g[..., None] * weights[i] for i, g in enumerate(others))
    else:
        weights = jnp.zeros((0, channels), values.dtype)
        albedo = s_ai * inverse[:, None]
        rest = jnp.zeros_like(masked)
    albedo = jnp.where(ok[:, None], jnp.maximum(albedo, 0), 0)
    residual = masked - a[..., None] * albedo[:, None, :] - rest
    full = jnp.insert(weights, per_point, jnp.zeros(channels, values.dtype), axis=0)
    return albedo, full, residual


def project_weights(
    columns: tuple[Float[Array, "P M"], ...],
    values: Float[Array, "P M C"],
    weight: Float[Array, "P M"],
    per_point: int = 0,
):
    """The albedo of every point and the global weights, eliminated in closed form.

    `columns[k]` is lobe k's value for unit weight at each observation, `weight` each
    observation's least-squares weight (0: not observed); `per_point` the lobe whose weight
    is per point (the diffuse one). Returns `(albedo (P, C), weights (K, C), cost)`:
    `weights[per_point]` is 0 (the albedo is per point), the cost is the weighted sum of
    squared residuals (finite or +inf).
    """
    albedo, weights, residual = projected_residuals(columns, values, weight, per_point)
    cost = jnp.sum(residual * residual)
    return albedo, weights, jnp.where(jnp.isfinite(cost), cost, jnp.inf)


def _columns(family, params, shading: TrackShading):
    """Each lobe's value for unit weight at every observation (P, M): at the corners,
    bilinearly combined like the image."""
    p, m = shading.shape
    return tuple(
        jnp.sum(c.reshape(p, m, 4) * shading.corner_weight, axis=-1)
        for c in design_columns(family, params, shading.samples)
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
        return self.family.build(self.params).with_weights(self.weights)


def _standard_errors(family, params, weights, albedo, shading, per_point, cost):
    """Standard errors of the global parameters with every albedo eliminated: from the
    Jacobian of the projected residuals (the albedos' clamped set held fixed), whose
    Gauss-Newton covariance is the global block of the joint one (a Schur complement)."""
    k, channels = weights.shape
    values, weight, observed = _values(shading), shading.weight, shading.observed
    free = albedo > 0
    globals_ = [i for i in range(k) if i != per_point]
    if not globals_ and params.shape[0] == 0:  # every weight is per point: nothing global
        return params, jnp.full((k, channels), jnp.nan, weights.dtype)

    def residuals(theta):
        w = theta[: len(globals_) * channels].reshape(len(globals_), channels)
        p = theta[len(globals_) * channels :]
        columns = _columns(family, p, shading)
        a, others, masked, s_aa, s_ai, s_ag, _, _ = _sums(columns, values, weight, per_point)
        rest = sum(g[..., None] * w[i] for i, g in enumerate(others)) if others else 0
        inverse = jnp.where(s_aa > 0, 1 / jnp.where(s_aa > 0, s_aa, 1), 0)
        fitted = s_ai - (jnp.einsum("gp,gc->pc", s_ag, w) if others else 0)
        rho = jnp.where(free, fitted * inverse[:, None], 0)
        return (masked - a[..., None] * rho[:, None, :] - rest).reshape(-1)

    theta = jnp.concatenate([weights[jnp.array(globals_, int)].reshape(-1), params])
    jacobian = jax.jacfwd(residuals)(theta)
    n_observed = jnp.sum(observed) * channels
    n_unknowns = theta.shape[0] + jnp.sum(free)
    dof = jnp.maximum(n_observed - n_unknowns, 1)
    information = jacobian.T @ jacobian
    covariance = cost / dof * jnp.linalg.pinv(information, hermitian=True)
    variance = jnp.diagonal(covariance)
    rank_deficient = jnp.linalg.matrix_rank(information) < theta.shape[0]
    stderr = jnp.where(rank_deficient | (variance < 0), jnp.inf, jnp.sqrt(jnp.abs(variance)))
    n_weights = len(globals_) * channels
    weights_stderr = jnp.full((k, channels), jnp.nan, weights.dtype)
    weights_stderr = weights_stderr.at[jnp.array(globals_, int)].set(
        stderr[:n_weights].reshape(len(globals_), channels)
    )
    return stderr[n_weights:], weights_stderr


@eqx.filter_jit
def _fit(shading, family, per_point, tolerance, grid, candidates, zoom, zoom_grid):
    values, weight, observed = _values(shading), shading.weight, shading.observed

    def cost(params):
        return project_weights(_columns(family, params, shading), values, weight, per_point)[2]

    dtype = values.dtype
    if family.names:
        search = grid_search(
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
        )
        params, half_width = search.params, search.half_width
    else:
        params = jnp.zeros((0,), dtype)
        half_width = params
    columns = _columns(family, params, shading)
    albedo, weights, best = project_weights(columns, values, weight, per_point)
    params_stderr, weights_stderr = _standard_errors(
        family, params, weights, albedo, shading, per_point, best
    )
    # The RMSE of every observation, unweighted: what a user compares with the noise.
    model = sum(
        c[..., None] * (albedo[:, None, :] if k == per_point else weights[k])
        for k, c in enumerate(columns)
    )
    residual = jnp.where(observed[..., None], values - model, 0)
    counted = jnp.sum(observed) * values.shape[-1]
    rmse = 255 * jnp.sqrt(jnp.sum(residual * residual) / jnp.maximum(counted, 1))
    return params, weights, albedo, best, rmse, params_stderr, weights_stderr, half_width


def _padded_points(shading: TrackShading) -> TrackShading:
    """`shading` with its points padded to a bucket size (`ctjax._buckets`), the padding
    unobserved (weight 0): captures of similar size share the BnB's compiled program."""
    p, m = shading.shape
    size = bucket(p)
    if size == p:
        return shading
    zeros = lambda a: jnp.concatenate([a, jnp.zeros((size - p, *a.shape[1:]), a.dtype)])  # noqa: E731
    return TrackShading(
        pad_leading(shading.samples, p * m * 4, size * m * 4),
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
    candidates: int = 4,
    zoom: int = 2,
    zoom_grid: int = 8,
) -> AlbedoMapFit:
    """The BRDF with one albedo per tracked point (see the module doc): the sigma BnB over
    closed-form solves in which every albedo and the global weights are eliminated.
    `grid` points per axis at the first level, `zoom_grid` at the later ones (see
    `grid_search`): each cost evaluation passes over every observation, and 8 points reach
    the same tolerance as 32 in 128 evaluations instead of 288 (40k points x 5 frames:
    0.95 s instead of 1.99 s, sigma within the final grid spacing).

    The global weights' per-point row (`rho_tilde`) reports the median albedo per channel.
    """
    observed = np.asarray(shading.observed)
    views = observed.sum(axis=1)
    k = len(family.weight_names)
    informative = int(np.sum(views[views > 1] - 1))
    if informative < 3 * (k - 1) + len(family.names) + 1:
        raise CtjaxError(
            f"{len(views)} tracked points with {int(observed.sum())} observations: too few "
            "points seen in two frames or more to separate the albedo from the BRDF (poses "
            "or depth wrong, or frames that do not overlap?)"
        )
    values = np.asarray(shading.values)[observed]
    if not np.all(np.isfinite(values)):
        raise CtjaxError("observed values contain NaN or inf")
    per_point = _per_point_index(family)
    params, weights, albedo, cost, rmse, p_err, w_err, half = _fit(
        _padded_points(shading), family, per_point, tolerance, grid, candidates, zoom, zoom_grid
    )
    albedo = albedo[: len(views)]
    seen = np.asarray(views > 1)
    median = np.median(np.asarray(albedo)[seen], axis=0) if seen.any() else np.zeros(3)
    weights = weights.at[per_point].set(jnp.asarray(median, weights.dtype))
    return AlbedoMapFit(
        params, weights, albedo, cost, rmse, p_err, w_err, half, int(observed.sum()), family
    )


@eqx.filter_jit
def _accumulate(
    brdf, light, per_point, corner_point, corner_normal, corner_pixel, corner_weight, values
):
    """One frame's view of N points: the diffuse column `a` (N,) and the global lobes'
    prediction `rest` (N, 3), for the albedo normal equations (sum a (I - rest), sum a^2);
    corners (N, 4, ...), `corner_weight` 0 where not observed."""
    samples = _shading_samples(
        light,
        corner_point.reshape(-1, 3),
        corner_normal.reshape(-1, 3),
        corner_pixel.reshape(-1, 2),
        corner_point.dtype,
    )
    columns = jax.vmap(lambda n, l, v, e: e * brdf.columns(n, l, v))(
        samples.normal, samples.light, samples.view, samples.irradiance
    )  # (N * 4, K)
    columns = jnp.einsum("nck,nc->nk", columns.reshape(-1, 4, columns.shape[-1]), corner_weight)
    a = columns[:, per_point]
    global_ = jnp.arange(columns.shape[-1]) != per_point
    rest = (columns * global_) @ brdf.weights
    return a, rest


def _padded(array: np.ndarray, padding: int, dtype) -> jax.Array:
    zeros = np.zeros((padding, *array.shape[1:]), array.dtype)
    return jnp.asarray(np.concatenate([array, zeros]), dtype)


def _albedo_of(
    capture, data, brdf, light, per_point, index, rows, cols, count, among, tolerance, dtype, chunk
):
    """Albedo (N, 3; NaN where not estimated) and view count (N,) of pixels of frame
    `index`, from all the frames that see them (see `albedo_maps`), and the own frame's
    residual (N, 3) under the albedo of the other views alone (NaN where they have none)."""
    camera = capture.camera
    world = world_points(camera, capture.frames[index], rows, cols)
    numerator = np.zeros((len(rows), 3))
    denominator = np.zeros((len(rows), 3))
    cosine = np.zeros(len(rows))
    seen_count = np.zeros(len(rows), int)
    own = None
    # Padded to a whole chunk: one compilation for every frame and chunk.
    as_jax = functools.partial(_padded, padding=chunk - len(rows), dtype=dtype)
    for other in partners(capture, index, count, among):
        obs = (
            observe_own(camera, data[index], rows, cols)
            if other == index
            else observe(camera, data[other], world, tolerance)
        )
        a, rest = _accumulate(
            brdf,
            light,
            per_point,
            as_jax(obs.corner_point),
            as_jax(obs.corner_normal),
            as_jax(obs.corner_pixel),
            as_jax(obs.corner_weight),
            as_jax(obs.values),
        )
        a, rest = np.asarray(a)[: len(rows)], np.asarray(rest)[: len(rows)]
        # Per channel: a channel clipped in this view says nothing of that channel's albedo.
        weight = obs.weight[:, None] * obs.channel_seen
        numerator += a[:, None] * (obs.values - rest) * weight
        denominator += (a * a)[:, None] * weight
        if other == index:
            own = (a, rest, obs.values, weight, a[:, None] * (obs.values - rest) * weight)
        seen = np.any(obs.channel_seen, axis=-1)
        cosine += a * a * seen
        seen_count += seen
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


def _frames_of(capture, brdf, light, frames, per_point, neighbours, tolerance, dtype, among=None):
    """For each frame of `frames` (all when None): its pixels with geometry (rows, cols)
    and their albedo, view count and own residual (`_albedo_of`), in chunks of at most
    `_MAP_CHUNK` pixels (bounded memory; one compilation for every frame and chunk)."""
    dtype = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
    tolerance = DEFAULT_TOLERANCE if tolerance is None else tolerance
    camera = capture.camera
    data = [FrameData.of(f) for f in capture.frames]
    available = len(capture) if among is None else len(among)
    count = available - 1 if neighbours is None else min(neighbours, available - 1)
    chunk = min(_MAP_CHUNK, camera.width * camera.height)
    for index in range(len(capture)) if frames is None else frames:
        rows, cols = np.nonzero(capture.frames[index].geometry_mask)
        albedo = np.full((len(rows), 3), np.nan)
        seen_count = np.zeros(len(rows), int)
        residual = np.full((len(rows), 3), np.nan)
        for start in range(0, len(rows), chunk):
            part = slice(start, start + chunk)
            albedo[part], seen_count[part], residual[part] = _albedo_of(
                capture,
                data,
                brdf,
                light,
                per_point,
                index,
                rows[part],
                cols[part],
                count,
                among,
                tolerance,
                dtype,
                chunk,
            )
        yield index, rows, cols, albedo, seen_count, residual


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
