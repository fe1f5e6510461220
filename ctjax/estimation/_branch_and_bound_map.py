"""The BRDF with an albedo map: rho_tilde per surface point and channel, F_tilde and sigma
shared, from all frames (beyond the paper, whose eq. 1 has one rho_tilde per capture).

Real tissue is textured, and a texture is indistinguishable from N.L in one frame; not
across frames, since the light moves with the camera (see `ctjax._tracks`). The unknowns:
one albedo per surface point p and channel c, the global linear weights g (F_tilde, or
several specular weights) and the nonlinear parameters (sigma). The model of observation m of
point p is

    I_pmc = rho_pc a_pm + sum_g w_gc b_gpm(sigma)                   a: the diffuse column

For fixed sigma it is linear in (rho, w) >= 0, and each point's albedo appears only in its
own observations, so it is eliminated in closed form (variable projection:
`ctjax.estimation._variable_projection`), which leaves a nonnegative least squares in the few
global weights. The sigma branch-and-bound is then the same batched grid of closed-form
solves as the paper's, with 10^5 albedos eliminated instead of searched.

A point observed once has its albedo fitted exactly (no residual): it tells nothing about
sigma and w, and counts for nothing in their fit. Given the fit, its albedo is still
determined by its one observation (every pixel's albedo: `ctjax.estimation._dense_maps`).
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._buckets import bucket
from .._errors import CtjaxError
from .._numerics import safe_normalize
from .._programs import persistent_jit
from .._tracks import Tracks
from .._typing import Array, Bool, Float, Scalar
from .._vector import Vec3
from ..lights import AbstractLight
from ..lights._point import default_light
from ..observations import ShadingSamples
from ._branch_and_bound import grid_search
from ._brdf import PAPER, BRDFFamily, design_geometry
from ._variable_projection import (
    albedo_from_other_views,
    over_views,
    project_weights,
    projected_residuals,
    weighted_sums,
)

# Grid points evaluated at once by the BnB (each a pass over every observation's corners):
# one, measured: 80 evaluations on 16k tracks x 8 views took 0.11 s one at a time, 0.22 s
# two at a time and 0.29 s eight at a time (XLA's CPU code reduces the leading axes of the
# batched (sigmas, views, points) arrays element by element).
_GRID_BATCH = 1
# The BnB's first `_COARSE_LEVELS` levels evaluate every `_COARSE_STEP`-th track (`_fit`).
_COARSE_STEP = 4
_COARSE_LEVELS = 2


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


def _shade(light: AbstractLight, point: Vec3, normal: Vec3, pixel, eye=None):
    """(N, L, V, irradiance) at one corner; `eye`: the viewer where it is not the light's
    lens (a stereo scope's right camera, as in `shade`)."""
    to_lens = safe_normalize(-point)
    view = to_lens if eye is None else safe_normalize(eye - point)
    direction, irradiance = light.illuminate(point, to_lens, pixel)
    return normal, direction, view, irradiance


def _views_first(array):
    """`ctjax._tracks.views_first` traced (XLA fuses the transposition into its consumers:
    in NumPy it was 40% of the tracks' shading)."""
    if array.ndim == 2:
        return array.T
    moved = jnp.moveaxis(array, (0, 2), (2, 0))
    return moved if array.ndim == 3 else moved.reshape(-1, array.shape[-1])


@persistent_jit
def _track_shading(
    light, point, normal, pixel, corner_weight, values, weight, eye=None
) -> TrackShading:
    # Compiled (and kept between processes): op by op, a new process spent 0.2 s lowering
    # each operation of the light's model.
    point, normal, pixel = (_views_first(a) for a in (point, normal, pixel))
    where = [Vec3.from_array(point), Vec3.from_array(normal), (pixel[:, 0], pixel[:, 1])]
    where += [] if eye is None else [Vec3.from_array(_views_first(eye))]
    n, l, v, e = jax.vmap(lambda *x: _shade(light, *x))(*where)
    samples = ShadingSamples(n, l, v, e, jnp.zeros((len(point), 3), point.dtype))
    return TrackShading(
        samples, _views_first(corner_weight), _views_first(values), _views_first(weight)
    )


def track_shading(tracks: Tracks, light: AbstractLight | None = None, dtype=None):
    """`tracks` under `light` (the paper's, L = V, by default) as `TrackShading` (views
    from a stereo scope's right camera, `Tracks.corner_eye`, with their own V)."""
    dtype = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
    as_host = lambda a: np.asarray(a, dtype)  # noqa: E731
    return _track_shading(
        default_light(light),
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
        None if tracks.corner_eye is None else as_host(tracks.corner_eye),
    )


def _per_point_index(family: BRDFFamily) -> int:
    if "rho_tilde" not in family.weight_names:
        raise CtjaxError(f"BRDF family {family.names} has no rho_tilde weight to map")
    return family.weight_names.index("rho_tilde")


def _corner_geometry(family, shading: TrackShading):
    """What the columns take of the tracks whatever the nonlinear parameters (computed once
    for the BnB): each lobe's `geometry` at every observation's corners (flattened 4 M P),
    and the corners' bilinear weights times the irradiance (4, M, P)."""
    corners = shading.corner_weight
    irradiance = shading.samples.irradiance.reshape(corners.shape)
    return design_geometry(family, shading.samples), corners * irradiance


def track_columns(family, params, shading: TrackShading, corners=None):
    """Each lobe's value for unit weight at every observation (M, P): at the corners,
    bilinearly combined like the image. `corners`: `_corner_geometry(family, shading)`
    (computed here otherwise)."""
    geometry, factor = _corner_geometry(family, shading) if corners is None else corners
    return tuple(
        over_views(c.reshape(factor.shape) * factor)  # the four corners: leading axis
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
        s = weighted_sums(
            track_columns(family, p, shading), shading.values, shading.weight, per_point
        )
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


def _covariance_errors(information: np.ndarray, scale) -> np.ndarray | None:
    """sqrt(diag(scale * information^-1)); None where the information is rank-deficient."""
    n = information.shape[0]
    # jnp.linalg's default tolerances, in the information's own precision.
    rtol = 10 * n * np.finfo(information.dtype).eps
    if np.linalg.matrix_rank(information, hermitian=True) < n:
        return None
    variance = np.diagonal(scale * np.linalg.pinv(information, rcond=rtol, hermitian=True))
    return np.where(variance < 0, np.inf, np.sqrt(np.abs(variance)))


def _standard_errors(
    information, scale, weight_names, per_point: int, channels: int, at_bound=None
):
    """The standard errors of the nonlinear parameters (D,) and of the global weights (K, C;
    NaN in the per-point row) from `_information`, in NumPy: a matrix this small is not
    worth LAPACK kernels in the compiled program.

    `at_bound` (D,) marks parameters at an end of their box. Where the information is
    rank-deficient with them and not without them (a diffuse roughness at 0, where the
    shading's derivative in it vanishes), they are held at the bound (an active
    constraint): the others' errors are conditional on it, theirs are inf."""
    information, scale = np.asarray(information), np.asarray(scale)
    n, k = information.shape[0], len(weight_names)
    n_weights = (k - 1) * channels
    weights_stderr = np.full((k, channels), np.nan, information.dtype)
    if n == 0:
        return np.zeros(0, information.dtype), weights_stderr
    stderr = _covariance_errors(information, scale)
    bound = np.zeros(n, bool)
    bound[n_weights:] = False if at_bound is None else np.asarray(at_bound, bool)
    if stderr is None and bound.any():
        kept = _covariance_errors(information[np.ix_(~bound, ~bound)], scale)
        if kept is not None:
            stderr = np.full(n, np.inf, information.dtype)
            stderr[~bound] = kept
    if stderr is None:
        stderr = np.full(n, np.inf, information.dtype)
    globals_ = [i for i in range(k) if i != per_point]
    weights_stderr[globals_] = stderr[:n_weights].reshape(len(globals_), channels)
    return stderr[n_weights:], weights_stderr


@persistent_jit
def _fit(shading, family, per_point, tolerance, grid, candidates, zoom, zoom_grid):
    values, weight, observed = _values(shading), shading.weight, shading.observed

    # What the columns take of the tracks whatever sigma: computed once, not per evaluation.
    corners = _corner_geometry(family, shading)

    def cost(params, shading=shading, corners=corners):
        columns = track_columns(family, params, shading, corners)
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
    columns = track_columns(family, params, shading, corners)
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
            "or depth wrong, frames that do not overlap, or most views clipped?)"
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
    p, h = np.asarray(params, float), np.asarray(half, float)
    at_bound = (p - h <= np.asarray(family.lo, float)) | (p + h >= np.asarray(family.hi, float))
    errors = _standard_errors(
        *information, family.weight_names, per_point, weights.shape[1], at_bound
    )
    p_err, w_err = map(jax.device_put, errors)
    return AlbedoMapFit(
        params, weights, albedo, cost, rmse, p_err, w_err, half, int(observed.sum()), family
    )


# A lobe "shows" at an observation where it predicts at least this (linear units: one
# 8-bit level), in some channel.
LOBE_SHOWS = 1 / 255


@persistent_jit
def _where_lobes_show(family, params, shading: TrackShading, per_point: int):
    """Sums of squared weighted residuals of `family` at `params` and of its diffuse lobe
    alone at the same `params` (its shape as fitted), every albedo and global weight
    projected out, over the observations where `family`'s lobes other than the per-point one
    predict at least `LOBE_SHOWS`; and their number. Then, for each observation (M, P),
    the weighted products of its measured and predicted RGB and of the predicted with
    itself, each view predicted with its point's albedo from the point's other views (0
    where those are too few: `albedo_from_other_views`), for `frame_brightness`; and the
    weighted residuals (C, M, P), for `rgb_rmse_recorded`."""
    columns = track_columns(family, params, shading)
    _, weights, residual = projected_residuals(columns, shading.values, shading.weight, per_point)
    others = [c[None] * weights[k][:, None, None] for k, c in enumerate(columns) if k != per_point]
    if others:
        lobes = sum(others[1:], others[0])
        shows = (jnp.max(lobes, axis=0) >= LOBE_SHOWS) & (shading.weight > 0)
    else:  # the diffuse lobe alone (a Lambertian fit's brightness): no max over a constant 0,
        # which XLA folds at compile time (1.9 s and an alarm on stderr at 28 x 640 px frames)
        lobes, shows = 0.0, jnp.zeros(shading.weight.shape, bool)
    _, _, plain_residual = projected_residuals(
        (columns[per_point],), shading.values, shading.weight, 0
    )
    ssr = lambda r: jnp.sum(jnp.where(shows[None], r * r, 0))  # noqa: E731
    a, w = columns[per_point], shading.weight
    albedo, ok = albedo_from_other_views(a, shading.values - lobes, w, w > 0)
    predicted = a * albedo + lobes
    across = jnp.where(ok, w * jnp.sum(shading.values * predicted, axis=0), 0)
    power = jnp.where(ok, w * jnp.sum(predicted * predicted, axis=0), 0)
    return ssr(residual), ssr(plain_residual), jnp.sum(shows), across, power, residual


def lobe_gain_where_it_shows(fit: AlbedoMapFit, shading: TrackShading) -> tuple[float, int]:
    """What `fit`'s specular lobes bring where they show: 1 - RMSE / RMSE of its diffuse
    lobe alone (Lambertian for the paper's model; a diffuse lobe with a shape keeps the
    fitted one) over the observations where the lobes predict at least one 8-bit level,
    every point's albedo eliminated; and how many observations that is (0:
    the lobes show nowhere, gain 0).

    Over every observation a lobe that the data determine well can bring under 0.5%: a
    laparoscope's highlights are few and mostly clipped (measured with the near light: a
    light 7 mm off the lens with inverse-square and spot falloff, F_tilde 0.3 and sigma 0.2
    recovered within 7% and 4%, lowered the RMSE of every observation by 0.26% and that of
    the 70 observations where the lobe shows by 30%)."""
    per_point = fit.family.weight_names.index("rho_tilde")
    if len(fit.family.weight_names) == 1:  # the diffuse lobe alone: no lobe to show
        return 0.0, 0
    fit_ssr, plain_ssr, count, *_ = _where_lobes_show(
        fit.family, jnp.asarray(fit.params), shading, per_point
    )
    count, fit_ssr, plain_ssr = int(count), float(fit_ssr), float(plain_ssr)
    if count == 0 or not plain_ssr > 0 or not np.isfinite(fit_ssr):
        return 0.0, count
    return 1 - math.sqrt(fit_ssr / plain_ssr), count


def frame_brightness(fit: AlbedoMapFit, shading: TrackShading, frame) -> dict[int, float]:
    """Each frame's measured over predicted brightness under `fit`, by frame index: the
    gain g minimising sum w |measured - g predicted|^2 over the frame's views (`frame`: the
    frame index of each observation, (M, P) as `shading.weight`; -1: not counted), each view
    predicted with its point's albedo from the point's views in the other frames (a point
    seen in one frame predicts nothing). 1 for every frame where the model accounts for the
    frames' brightness; a spread is an exposure change (a scope's auto-exposure) or a
    falloff with distance that the model lacks, which the lobe then absorbs. NaN for a
    frame with no predicted view. As `HeldOutTracks.frame_brightness` for the LM fitters."""
    per_point = fit.family.weight_names.index("rho_tilde")
    *_, across, power, _ = _where_lobes_show(
        fit.family, jnp.asarray(fit.params), shading, per_point
    )
    across, power, frame = np.asarray(across), np.asarray(power), np.asarray(frame)
    out = {}
    for f in sorted({int(f) for f in np.unique(frame) if f >= 0}):
        here = frame == f
        total = float(np.sum(power[here]))
        out[f] = float(np.sum(across[here])) / total if total > 0 else math.nan
    return out


def rgb_rmse_recorded(fit: AlbedoMapFit, shading: TrackShading, gain) -> float:
    """The RMSE (8-bit levels) of `fit` over every observation of `shading`, whose values
    are the recorded ones over `gain` (M, P: each view's, a frame's exposure undone), in
    the recorded values: each residual times its view's gain (`fit.rgb_rmse` is in the
    values' units)."""
    per_point = fit.family.weight_names.index("rho_tilde")
    *_, residual = _where_lobes_show(fit.family, jnp.asarray(fit.params), shading, per_point)
    weight = np.asarray(shading.weight, float)
    observed = weight > 0
    if not observed.any():
        return math.nan
    scale = np.asarray(gain, float)[observed] / np.sqrt(weight[observed])
    recorded = np.asarray(residual, float)[:, observed] * scale
    return 255 * math.sqrt(float(np.mean(recorded * recorded)))
