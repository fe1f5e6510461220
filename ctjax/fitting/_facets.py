"""Facets: the specular lobe about each surface point's own normal, read from the views in
which the point shone.

Wet tissue's highlights are sparkles: facets finer than any reconstruction, each lit where
its own normal lies along H. A lobe about the reconstruction's smooth normals puts its
highlight where those normals meet H and moves it over the surface as the scope moves;
the sparkles stay on their facets (on the shared real sequences a pixel of S lands in S of
the next frame 64-99% of the time, against 1-6% for a pixel at random:
`benchmarks/facet_normals.py`). So each tracked point gets its own normal for the lobe
(the diffuse term keeps the reconstruction's), chosen among "no lobe", the
reconstruction's normal and H of each of the point's views (the facet that would have
made that view the point's peak) turned across the arc the views' H trace
(`FACET_ACROSS_RAD`), by the least squares of the other views with the point's albedo
fitted; a facet other than "no lobe" must lower them by more than `penalty` (2-level)^2
units, an AIC-like price for its two angles (the reconstruction's normal by a hundredth of
that: a fainter lobe is none). The lobe's sigma and F_tilde stay global.

Judged as `heldout_map_rmse` judges a model (each view predicted from the point's other
views, the albedo a nuisance), with the facet a second nuisance of the lobe: the facet
and the albedo of a judged view are chosen without it. `facet_lobe` (`_facet_lobe.py`)
picks sigma and one grey F_tilde from a grid (refined between its points) by that
protocol on the calibration tracks alone, then judges the held-out views;
`turned="diffuse"` gives the Lambertian model the same freedom for its own normal, the
fair comparison.
"""

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._buckets import padded
from .._convert import on_device
from .._errors import ParameterError
from .._model import ShadingModel
from .._programs import persistent_jit
from ..estimation._variable_projection import OTHER_VIEWS_SHARE
from ..lobes._paper import cook_torrance_brdf
from ..solvers import DenseLM, least_squares
from ._facet_geometry import (
    FACET_ACROSS_RAD,
    CandidateSet,
    grouped_per_point,
    lobe_columns,
)
from ._map_least_squares import TrackSamples, diffuse_lobe
from ._parameters import strongly_typed

# The price of a facet, in units of (2 levels)^2 (about the real sequences' noise floor,
# 1.7-2.5 levels): AIC's 2 per parameter, two angles.
FACET_PENALTY = 4.0
_LEVEL = 2.0 / 255
# The held-out judgement's facets, each chosen H then turned by two angles (LM steps): the
# views' own H are as coarse as a sharp lobe (1-4 degrees apart on the real sequences).
FACET_REFINE_STEPS = 10
_POINTS_AT_ONCE = 512  # points per batch of `lax.map`: (M + 2) x 4M lobe evaluations each
# The reconstruction's normal's price, in `penalty`'s units: a lobe that lowers the other
# views' squared error by less than (0.2 level)^2 is none. Without it the choice between
# no lobe and a faint one was the costs' rounding: on the shared cholecystectomy 31% of
# the judged views took a lobe in float32, 41% in float64 (26% both with this price, the
# held-out RMSE 0.01 level lower).
_FAINT = 0.01


def _one_point(
    model, turned, penalty, rotations, gains, subsets, sets, point, normal, pixel, weight,
    values, w, judged, frame, facets,
):  # fmt: skip
    """One tracked point (its M views), for each set of candidates it may choose among
    (`sets`: masks over the turns of `candidate_facets`), each subset of its frames (`subsets`:
    None all, 0 the even, 1 the odd frames) and each set of lobe weights `gains` (G, K,
    C): each judged view's residual (T, S, G, C, M) with the facet and the albedo chosen
    from the point's other views of the subset, the counted views (T, S, G, M) and the
    candidate taken per view (T, S, G, M: -1 not judged, 0 no lobe, 1 the reconstruction's
    normal, 2 + c candidate facet c); `facets` (J, 3): the candidate facets in world
    coordinates (`candidate_facets`, c of view c % M). The lobes' columns depend neither on
    their weights, nor on the subset, nor on the set: every choice shares them."""
    diffuse = diffuse_lobe(model)
    others = [k for k in range(len(model.brdf.lobes)) if k != diffuse]
    smooth, about = lobe_columns(model, turned, rotations, point, normal, pixel, weight, frame)
    off = smooth.at[jnp.array(others)].set(0.0) if others else smooth
    candidates = jnp.concatenate([off[None], smooth[None], jax.vmap(about)(facets)])  # (J+2, K, M)
    subset_weights = jnp.stack(
        [w if s is None else jnp.where(frame % 2 == s, w, 0.0) for s in subsets]
    )
    masks = jnp.asarray(np.repeat(np.asarray(sets, bool), w.shape[0], axis=1))  # (T, J)

    def chosen(w):  # (G, T, ...) -> (T, G, ...)
        out = _chosen_facets(diffuse, others, penalty, gains, candidates, values, w, judged, masks)
        return jax.tree.map(lambda x: jnp.moveaxis(x, 1, 0), out)

    return jax.tree.map(lambda x: jnp.moveaxis(x, 0, 1), jax.vmap(chosen)(subset_weights))


def _chosen_facets(diffuse, others, penalty, gains, candidates, values, w, judged, masks):
    """`_one_point` for one subset's view weights `w` (M,), for each set's mask (T, J) over
    the candidate facets: (G, T, ...). The candidates' costs are the sets' alike.

    Every view is predicted with the albedo fitted to the point's other views. Per
    candidate, the weighted sums over the views but view m of the products of the values
    and the lobes' columns do not depend on the lobe weights: they are summed once, and
    each set of weights only combines them (a view's cost is quadratic in the weights, its
    albedo linear). Half the time of predicting every view for every set of weights."""
    views = w.shape[0]
    facets = candidates.shape[0] - 2
    others = jnp.asarray(others, int)
    a = candidates[:, diffuse]  # (J + 2, M): each candidate's diffuse column
    s = candidates[:, others]  # (J + 2, L, M): the other lobes' columns

    def without_view(x):  # (..., M) weighted products -> their sums over the other views
        return jnp.sum(x, -1, keepdims=True) - x

    o_aa = without_view(w * a * a)  # (J + 2, M)
    o_av = without_view(w * a[:, None] * values)  # (J + 2, C, M)
    o_as = without_view(w * a[:, None] * s)  # (J + 2, L, M)
    o_vs = without_view(w * values[None, :, None] * s[:, None])  # (J + 2, C, L, M)
    o_ss = without_view(w * s[:, :, None] * s[:, None])  # (J + 2, L, L, M)
    # 1 / o_aa, 0 where the other views see no diffuse light (then o_av = o_as = 0 too).
    inverse = jnp.where(o_aa > 0, 1 / jnp.where(o_aa > 0, o_aa, 1.0), 0.0)[:, None]
    ok = judged & (w > 0) & (o_aa[0] >= OTHER_VIEWS_SHARE * w * a[1] * a[1]) & (o_aa[0] > 0)
    # A facet about view j's H is there wherever view j is counted, the judged view's own
    # included: a direction, which the other views' values choose or not.
    source = jnp.arange(facets) % views
    usable = (w > 0)[None, :] & (w[source] > 0)[:, None]  # (c, m)
    price = jnp.concatenate([jnp.zeros(1), penalty[None] * _FAINT, jnp.full(facets, penalty)])[
        :, None
    ]
    index = jnp.arange(facets + 2)[:, None]
    on_view = jnp.arange(views)

    def choose(g):  # (K, C): one set of lobe weights
        g = g[others]  # (L, C)
        # The other views' sums with target = values - lobes, albedo = max(o_at, 0) / o_aa
        # and cost = o_tt - albedo o_at, summed over the channels; o_tt less the values'
        # own sum of squares, which every candidate shares (the costs' differences exact
        # where a candidate's lobe is faint).
        o_at = o_av - jnp.sum(g[None, :, :, None] * o_as[:, :, None], 1)  # (J + 2, C, M)
        o_tt = jnp.sum((g @ g.T)[None, :, :, None] * o_ss, (1, 2)) - 2 * jnp.sum(
            g.T[None, :, :, None] * o_vs, (1, 2)
        )
        positive = jnp.maximum(o_at, 0.0)
        cost = o_tt - jnp.sum(positive * positive * inverse, 1) + price  # (J + 2, M)
        albedo = positive * inverse

        def among(mask):  # one set's choice
            allowed = jnp.concatenate([jnp.ones((2, views), bool), mask[:, None] & usable])
            priced = jnp.where(allowed, cost, jnp.inf)
            least = jnp.min(priced, 0)  # the first least: ties go to "no lobe"
            best = jnp.min(jnp.where(priced == least, index, facets + 2), 0)
            lobes = jnp.sum(g[:, :, None] * s[best, :, on_view].T[:, None], 0)  # (C, M)
            chosen = values - lobes - a[best, on_view] * albedo[best, :, on_view].T
            return jnp.where(ok, chosen, 0.0), jnp.where(ok, w, 0.0), jnp.where(ok, best, -1)

        return jax.vmap(among)(masks)

    return jax.vmap(choose)(gains)


def _turned_view(
    model, turned, rotations, point, normal, pixel, weight, values, w, judged, frame, facets,
    view, start, steps,
):  # fmt: skip
    """View `view`'s residual (C,) of one tracked point with its candidate facet `start`
    turned by two angles to fit the point's other views (`_refined`)."""
    diffuse = diffuse_lobe(model)
    others = [k for k in range(len(model.brdf.lobes)) if k != diffuse]
    _, about = lobe_columns(model, turned, rotations, point, normal, pixel, weight, frame)
    return _refined(
        about, view, facets[start], values, w, diffuse, others, model.brdf.weights, steps
    )


# The refined facet's prior: a Gaussian of this width (radians) about the view's H, worth
# one (2-level) unit of residual there.
_REFINE_PRIOR_RAD = 0.05


def _refined(about, m, start, values, w, diffuse, others, gains, steps):
    """View m's residual (C,) with the facet started at `start` (world) turned by two
    angles to fit the point's other views (the albedo in closed form, a prior about
    `start`: `_REFINE_PRIOR_RAD`)."""
    helper = jnp.where(jnp.abs(start[0]) < 0.9, jnp.array([1.0, 0, 0]), jnp.array([0, 1.0, 0]))
    t1 = jnp.cross(start, helper.astype(start.dtype))
    t1 = t1 / jnp.linalg.norm(t1)
    t2 = jnp.cross(start, t1)
    keep = jnp.where((w > 0) & (jnp.arange(w.shape[0]) != m), w, 0.0)

    def predict(x):
        facet = start + x[0] * t1 + x[1] * t2
        c = about(facet / jnp.linalg.norm(facet))
        a = c[diffuse]
        rest = sum((c[k][None] * gains[k][:, None] for k in others), jnp.zeros_like(values))
        target = values - rest
        albedo = jnp.sum(keep * a * target, -1, keepdims=True)
        albedo = jnp.maximum(albedo / jnp.maximum(jnp.sum(keep * a * a), 1e-30), 0.0)
        return target - a * albedo  # (C, M)

    def residuals(x):
        r = jnp.sqrt(keep) * predict(x)
        return jnp.concatenate([r.reshape(-1), _LEVEL * x / _REFINE_PRIOR_RAD])

    x = least_squares(residuals, DenseLM(), jnp.zeros(2, values.dtype), steps)[0]
    return predict(x)[:, m]


@persistent_jit
def _facet_views(
    model, samples: TrackSamples, judged, rotations, penalty, turned: str, candidates, gains
):
    """For each set of lobe weights `gains` (G, K, C): every judged view's residual
    (G, C, M, P), counted weight (G, M, P) and candidate taken (G, M, P; `_one_point`)."""
    per_point = grouped_per_point(model, samples, judged, rotations, candidates)

    every = ((True,) * len(candidates.across),)

    def one(arrays):
        residual, w, best = _one_point(
            model, turned, penalty, rotations, gains, (None,), every, *arrays
        )
        return residual[0, 0], w[0, 0], best[0, 0]

    residual, w, best = jax.lax.map(one, per_point, batch_size=_POINTS_AT_ONCE)
    return jnp.moveaxis(residual, 0, -1), jnp.moveaxis(w, 0, -1), jnp.moveaxis(best, 0, -1)


@persistent_jit
def _facet_sums(
    model, samples: TrackSamples, judged, rotations, penalty, turned: str, candidates, gains,
    subsets,
):  # fmt: skip
    """`_facet_views` per set of candidates chosen among (`candidates.sets`) and subset of
    the frames (`_one_point`) summed per tracked point: (T, S, G, 2, P), the judged views'
    sum of squares and count of values."""
    per_point = grouped_per_point(model, samples, judged, rotations, candidates)

    def one(arrays):
        residual, w, _ = _one_point(
            model, turned, penalty, rotations, gains, subsets, candidates.sets, *arrays
        )
        ssr = jnp.sum(w * jnp.sum(residual * residual, -2), -1)  # (T, S, G)
        return jnp.stack([ssr, residual.shape[-2] * jnp.sum(w, -1)], -1)  # (T, S, G, 2)

    return jnp.moveaxis(jax.lax.map(one, per_point, batch_size=_POINTS_AT_ONCE), 0, -1)


@persistent_jit
def _turned_views(
    model, samples: TrackSamples, judged, rotations, turned: str, candidates, pairs, steps: int
):
    """The residuals (N, C) of the views `pairs` (N, 3: point, view, the view whose H it
    took) with that H turned (`_turned_view`)."""
    per_point = grouped_per_point(model, samples, judged, rotations, candidates)

    def one(pair):
        arrays = [x[pair[0]] for x in per_point]
        return _turned_view(model, turned, rotations, *arrays, pair[1], pair[2], steps)

    return jax.lax.map(one, pairs, batch_size=_POINTS_AT_ONCE)


class FacetJudgement(eqx.Module):
    """A model judged with a facet per point: `rmse` (8-bit levels) over the judged views,
    `with_facet` the share of them whose facet is not "no lobe", `residual` (C, M, P;
    levels, 0 where not judged), `weight` (M, P) and `facet` (M, P: -1 no lobe or not
    judged, M the reconstruction's normal, j a facet about H of view j)."""

    rmse: float
    with_facet: float
    residual: np.ndarray
    weight: np.ndarray
    facet: np.ndarray


def facet_heldout(
    model: ShadingModel,
    samples: TrackSamples,
    judged,
    rotations,
    *,
    penalty: float = FACET_PENALTY,
    turned: str = "lobe",
    shuffle_seed: int | None = None,
    refine_steps: int = 0,
    across: Sequence[float] = FACET_ACROSS_RAD,
) -> FacetJudgement:
    """Judge `model` (fixed) on the `judged` views (M, P) of `samples`, each predicted with
    the point's facet and albedo chosen from its other views (see the module).
    `rotations` (F, 3, 3): every frame's camera-to-world rotation (`samples.site.frame`
    indexes it). `turned`: `"lobe"` (the lobes' normal chosen), `"diffuse"` (the diffuse
    term's: the same freedom for a model without a lobe) or `"both"` (one facet for the
    lobes and the diffuse term: whether a lobe adds to each point's normal turned; on the
    second sinus video no, on a SCARED da Vinci stretch yes, docs/real-video.md).
    `shuffle_seed`: the control, every
    point's candidate facets those of another point (a permutation of that seed): whether a
    point's own views carry what the facets gain. `refine_steps`: each chosen facet then
    turned by two angles (Levenberg-Marquardt, at most that many steps) to fit the other
    views. `across`: the candidate facets, each view's H turned across the views' arc by
    each of these angles (rad; `(0.0,)`: the views' H as they are)."""
    if turned not in ("lobe", "diffuse", "both"):
        raise ParameterError(f"turned must be 'lobe', 'diffuse' or 'both', got {turned!r}")
    if tuple(getattr(model, "effects", ())):
        raise ParameterError("facets judge a model without image effects")
    if samples.eye is not None:
        raise ParameterError("facets need every view seen from the light's lens (no right views)")
    return _judgements(model, samples, judged, rotations, None, penalty, turned, shuffle_seed,
                       refine_steps, across)[0]  # fmt: skip


def facet_arguments(
    model, samples, judged, rotations, F_tildes, penalty, shuffle_seed, across, choices=None
):
    """The arguments of `_facet_views` and `_facet_sums` but `samples` and `turned`:
    the lobe weights (G, K, C) are `model`'s (`F_tildes` None) or each grey F_tilde of
    `F_tildes` for every lobe but the diffuse one."""
    model = strongly_typed(model)
    dtype = samples.weight.dtype
    weights = np.asarray(model.brdf.weights, dtype)
    if F_tildes is None:
        gains = weights[None]
    else:
        gains = np.repeat(np.asarray(F_tildes, dtype)[:, None, None], weights.shape[0], 1)
        gains = np.repeat(gains, weights.shape[1], 2)
        gains[:, diffuse_lobe(model)] = weights[diffuse_lobe(model)]
    # Every point's own candidates, or (the control) another point's: a permutation either
    # way, so that a judgement and its control are one compiled program.
    points = samples.weight.shape[1]
    order = np.arange(points)
    if shuffle_seed is not None:
        order = np.random.default_rng(shuffle_seed).permutation(points)
    shuffle = on_device(order)
    return (
        model,
        jnp.asarray(judged, bool),
        jnp.asarray(np.asarray(rotations), dtype),
        jnp.asarray(penalty * _LEVEL**2, dtype),
        _candidate_set(shuffle, across, choices),
        jnp.asarray(gains),
    )


def _candidate_set(shuffle, across, choices) -> CandidateSet:
    """The candidates turned by `across` (rad), chosen among all of them or, per choice of
    `choices`, among those turned by its angles (each a subset of `across`)."""
    across = tuple(float(a) for a in across)
    choices = (across,) if choices is None else tuple(tuple(map(float, c)) for c in choices)
    if any(not set(c) <= set(across) for c in choices):
        raise ParameterError(f"candidate sets {choices} are not among the turns {across}")
    return CandidateSet(shuffle, across, tuple(tuple(a in c for a in across) for c in choices))


def _judgements(
    model, samples, judged, rotations, F_tildes, penalty, turned, shuffle_seed, refine_steps,
    across,
) -> list[FacetJudgement]:  # fmt: skip
    """`facet_heldout` for `model`'s lobe weights (`F_tildes` None) or for each grey
    F_tilde of `F_tildes` in turn (the lobes' columns shared; not turned)."""
    model, judged, rotations, price, candidates, gains = facet_arguments(
        model, samples, judged, rotations, F_tildes, penalty, shuffle_seed, across
    )
    if F_tildes is not None:
        refine_steps = 0
    views = _facet_views(model, samples, judged, rotations, price, turned, candidates, gains)
    return [
        _judged(model, samples, judged, rotations, turned, candidates, refine_steps, *one)
        for one in zip(*(np.array(x) for x in views), strict=True)
    ]


def facet_sums(
    model, samples, judged, rotations, F_tildes, penalty, shuffle_seed=None, subsets=(None,),
    across=FACET_ACROSS_RAD, choices=None, turned="lobe",
):  # fmt: skip
    """Per set of candidates (`choices`: each the turns of `across` a point chooses among;
    None: one, all of them), subset of the frames (`subsets`: None all, 0 the even, 1 the
    odd frames), grey F_tilde of `F_tildes` and tracked point (T, S, G, 2, P): the judged
    views' sum of squared residuals (8-bit levels^2) and count of values, with the facet
    and the albedo chosen from the point's other views of the subset (`facet_heldout`'s,
    not turned), summed where they are computed: the grid's figures without its residual
    arrays. The sets and the subsets share the lobes' columns (one pass for all).
    `across`: the candidate facets, `turned`: the terms turned to a facet (`facet_heldout`)."""
    if turned not in ("lobe", "diffuse", "both"):
        raise ParameterError(f"turned must be 'lobe', 'diffuse' or 'both', got {turned!r}")
    model, judged, rotations, price, candidates, gains = facet_arguments(
        model, samples, judged, rotations, F_tildes, penalty, shuffle_seed, across, choices
    )
    sums = _facet_sums(
        model, samples, judged, rotations, price, turned, candidates, gains, tuple(subsets)
    )
    return np.asarray(sums) * np.array([255.0**2, 1.0])[:, None]


def _judged(model, samples, judged, rotations, turned, candidates, refine_steps, residual,
            weight, best) -> FacetJudgement:  # fmt: skip
    """One set of lobe weights' `FacetJudgement` from `_facet_views`' arrays, the views
    that took a candidate facet turned first (`refine_steps`)."""
    if refine_steps:  # only the views that took a candidate facet are turned
        view, point = np.nonzero(best >= 2)
        if view.size:
            pairs = np.stack([point, view, best[view, point] - 2], -1).astype(np.int32)
            padded_pairs, _ = padded(pairs, len(pairs))
            turned_residual = _turned_views(
                model, samples, judged, rotations, turned, candidates,
                jnp.asarray(padded_pairs), int(refine_steps),
            )  # fmt: skip
            residual[:, view, point] = np.asarray(turned_residual)[: len(pairs)].T
    views = best.shape[0]
    facet = np.where(best <= 0, -1, np.where(best == 1, views, (best - 2) % views))
    total = float(np.sum(weight)) * residual.shape[0]
    ssr = float(np.sum(weight * residual * residual))
    counted = weight > 0
    return FacetJudgement(
        255 * math.sqrt(ssr / total) if total > 0 else math.nan,
        float(np.mean(facet[counted] >= 0)) if counted.any() else math.nan,
        255 * residual,
        weight,
        facet,
    )


def facet_model(light, sigma: float, F_tilde: float) -> ShadingModel:
    """The paper's BRDF (grey F_tilde) under `light`, for the facet protocol."""
    return strongly_typed(ShadingModel(cook_torrance_brdf(1.0, F_tilde, sigma), light))
