"""The lobe about every point's own facet chosen and judged (`facet_lobe`): sigma and one
grey F_tilde from a grid by the facet protocol (`ctjax.fitting._facets`) on the calibration
tracks, refined between the grid's points; whether the data determine it (the grid again on
the even and on the odd calibration frames, the gain against Lambert with its own normal
chosen the same way, the grid's ends: `FacetLobe.status`); the held-out views judged beside
Lambert's under the same light."""

import math
from collections.abc import Mapping, Sequence

import equinox as eqx
import numpy as np

from .._errors import ParameterError
from ._facet_geometry import FACET_ACROSS_RAD
from ._facet_status import (
    MIN_FRAMES_FOR_HALVES,
    facet_status,
    judged_status,
)
from ._facets import (
    FACET_PENALTY,
    FACET_REFINE_STEPS,
    facet_heldout,
    facet_model,
    facet_sums,
)
from ._map_least_squares import TrackSamples

# From sharper than the views resolve (on the real sequences the views' H are 0.02-0.07
# rad apart) to a broad sheen; an attached synthetic sparkle's lobe is 0.06.
FACET_SIGMAS = (0.025, 0.035, 0.05, 0.07, 0.1, 0.15, 0.2, 0.3, 0.45)
# F_tilde in steps of 1.47x (0.002 * 100^(k/12)): each sigma's pass serves every F_tilde at
# a small cost, and the parabola between 2-2.5x steps put F_tilde 20% low on a synthetic
# lobe (0.0094 for 0.012; 0.0113 with these, as with twice as many).
FACET_F_TILDES = (
    0.002, 0.00294, 0.00431, 0.00632, 0.00928, 0.0136, 0.02,
    0.0294, 0.0431, 0.0632, 0.0928, 0.136, 0.2,
)  # fmt: skip
# The candidate facets `facet_lobe` compares, by name (`facet_heldout`'s `across`): each
# view's H turned across the views' arc, and the views' H as they are. The one whose grid
# predicts the calibration views best is used: on attached synthetic sparkles (a facet
# lobe of 0.06, F_tilde 0.012) only the first recovers the lobe (sigma 0.067, F_tilde
# 0.0084, against 0.056 and 0.0027), on the shared sinus the second predicts the test
# frames better (0.806x Lambert against 0.832x; `benchmarks/facet_truth.py`,
# `benchmarks/facet_normals.py`).
FACET_CANDIDATES = {"across the arc": FACET_ACROSS_RAD, "the views' H": (0.0,)}
# The control's permutation of the points (`facet_heldout`'s `shuffle_seed`): every
# point's candidate facets another point's, the lobe the same.
CONTROL_SEED = 0


def halves_json(halves: tuple | None, parts=("even_frames", "odd_frames")) -> dict | None:
    """The choices on the even and on the odd calibration frames (or on `parts`), for JSON."""
    if halves is None:
        return None
    return {
        part: {"sigma": s, "F_tilde": f, "peak": f / s**2}
        for part, (s, f) in zip(parts, halves, strict=True)
    }


def views_step_json(step: tuple) -> dict:
    """`views_step`'s three medians, for JSON."""
    return dict(zip(("all_frames", "even_frames", "odd_frames"), step, strict=True))


def views_step(train: TrackSamples, rotations) -> tuple[float, float, float]:
    """How finely the calibration views sample a lobe: the median angle (rad) between a
    tracked point's consecutive views (by frame), each its direction to the scope in world
    coordinates (`rotations` (F, 3, 3): camera-to-world), on all the frames, then on the
    even and on the odd frames alone (the halves' spacing). With the light at the scope a
    view's H turns by about as much as its direction does. NaN where no point has two
    views."""
    weight = np.asarray(train.weight)  # (M, P)
    views, points = weight.shape
    frame = np.asarray(train.site.frame)
    point = train.point  # (4 M P) corners, views first (read on the host: no eager JAX)
    corners = np.stack(
        [np.asarray(c).reshape(4, views, points) for c in (point.x, point.y, point.z)], -1
    )
    corner_weight = np.asarray(train.corner_weight)  # (4, M, P)
    at = np.einsum("cmp,cmpd->mpd", corner_weight, corners)  # each view's point, camera frame
    direction = -at / np.maximum(np.linalg.norm(at, axis=-1, keepdims=True), 1e-12)
    rotations = np.asarray(rotations, float)
    world = np.einsum("mpij,mpj->mpi", rotations[np.maximum(frame, 0)], direction)
    order = np.argsort(np.where(weight > 0, frame, np.iinfo(np.int32).max), 0, kind="stable")
    counted = np.take_along_axis(weight > 0, order, 0)
    frame = np.take_along_axis(frame, order, 0)
    world = np.take_along_axis(world, order[..., None], 0)

    def median_step(part: int | None) -> float:
        last, seen, steps = np.zeros((points, 3)), np.zeros(points, bool), []
        for m in range(views):
            on = counted[m] if part is None else counted[m] & (frame[m] % 2 == part)
            both = on & seen
            cosine = np.sum(last[both] * world[m, both], -1)
            steps.append(np.arccos(np.clip(cosine, -1.0, 1.0)))
            last[on], seen = world[m, on], seen | on
        steps = np.concatenate(steps)
        return float(np.median(steps)) if steps.size else math.nan

    return median_step(None), median_step(0), median_step(1)


class FacetLobe(eqx.Module):
    """The lobe about every point's own facet (`facet_lobe`): `sigma` and `F_tilde` (grey)
    chosen on the calibration tracks, `calibration_rmse` (grid point -> RMSE, levels),
    `at_bound` (the choice at an end of its grid), the held-out RMSE of the lobe with facets
    (`rmse`), of the Lambertian model under the same light (`lambertian_rmse`) and of the
    Lambertian model with its own normal chosen the same way (`lambertian_turned_rmse`), the
    share of judged views with a facet (`with_facet`), the candidate facets used
    (`candidates`, a name of `FACET_CANDIDATES`) and each set's least calibration RMSE
    (`candidate_rmse`), by which it was chosen. Against synthetic truth
    (`benchmarks/facet_truth.py`) sigma reads within 20% and F_tilde 30-80% low: choosing
    the lobe that best predicts each view from the others hedges where the facets are
    uncertain, so `F_tilde` and `peak` are lower bounds: the status holds sigma to its
    precision and F_tilde only to a weight told from none (`facet_status`).

    Whether the data determine it: `halves` ((sigma, F_tilde) chosen on the even
    calibration frames alone, then on the odd; None with fewer than 6, and the status then
    `unstable`), `gain` (the lobe's
    relative RMSE decrease on the calibration frames against Lambert with its own normal
    chosen the same way), `stderr` (sigma's and F_tilde's standard errors over the tracked
    points: the choice again on `BOOTSTRAP_RESAMPLES` resamples of them), `status`
    (`"successful"` or the first of `ctjax._determined`'s statuses that applies) and
    `undetermined` (each reason, as `Estimate.details`); and `no_lobe` where the lobe
    predicts the held-out views no better than Lambert's model under the same light.
    `views_step`: how finely the calibration views sample the lobe (`views_step`: rad on
    all the frames, on the even and on the odd ones). `steady`: the judgement again without
    the held-out frames whose brightness the model does not follow (`facet_lobe`'s
    `unsteady`; None where none is left out): the frames left out and the three RMSEs.
    `turned`: the terms about the facet (`facet_lobe`'s: "lobe" or "both")."""

    sigma: float
    F_tilde: float
    calibration_rmse: dict
    at_bound: bool
    rmse: float
    lambertian_rmse: float
    lambertian_turned_rmse: float
    with_facet: float
    halves: tuple | None = None
    gain: float = math.nan
    status: str = "successful"
    undetermined: tuple = ()
    stderr: tuple = (math.nan, math.nan)
    candidates: str = "across the arc"
    candidate_rmse: dict = eqx.field(default_factory=dict)
    views_step: tuple = (math.nan, math.nan, math.nan)
    control_rmse: float = math.nan
    steady: dict | None = None
    turned: str = "lobe"

    @property
    def ratio(self) -> float:
        """Held-out RMSE with facets over the Lambertian model's under the same light."""
        return self.rmse / self.lambertian_rmse

    @property
    def control_ratio(self) -> float:
        """The control's `ratio`: the same lobe, its held-out views predicted with every
        point's candidate facets another point's (`CONTROL_SEED`). Near `ratio`, the gain is
        not the points' own highlights; near 1 or above, it is."""
        return self.control_rmse / self.lambertian_rmse

    @property
    def peak(self) -> float:
        """F_tilde / sigma^2: the lobe's height at N = H (Beckmann's D(0) = 1 / (pi
        sigma^2)), what a sparkle's brightness measures when the views are too far apart to
        resolve its width."""
        return self.F_tilde / self.sigma**2

    def to_json(self) -> dict:
        halves = halves_json(self.halves)
        return {
            "sigma": self.sigma,
            "F_tilde": self.F_tilde,
            "sigma_stderr": self.stderr[0],
            "F_tilde_stderr": self.stderr[1],
            "peak": self.peak,
            "status": self.status,
            "undetermined": list(self.undetermined),
            "at_bound": self.at_bound,
            "halves": halves,
            "calibration_gain": self.gain,
            "heldout_rgb_rmse": self.rmse,
            "lambertian_same_light_rgb_rmse": self.lambertian_rmse,
            "lambertian_turned_normals_rgb_rmse": self.lambertian_turned_rmse,
            "ratio": self.ratio,
            "control_ratio": self.control_ratio if math.isfinite(self.control_ratio) else None,
            "views_with_a_facet": self.with_facet,
            "candidates": self.candidates,
            "calibration_rmse_by_candidates": dict(self.candidate_rmse),
            "views_step_rad": views_step_json(self.views_step),
            "calibration_rgb_rmse": {
                f"sigma={s:g},F_tilde={f:g}": r for (s, f), r in self.calibration_rmse.items()
            },
            "steady_frames": self.steady,
            "turned": self.turned,
        }


def _grid(
    train, rotations, light, sigmas, F_tildes, penalty, shuffle_seed, subsets=(None,),
    candidates=None, turned="lobe",
):  # fmt: skip
    """Per set of candidate facets (`candidates`: name -> turns, `facet_heldout`'s
    `across`; default `FACET_CANDIDATES`) and subset of the frames (`subsets`: None all, 0
    the even, 1 the odd frames), every grid point's calibration RMSE (a dict), each view of
    `train` judged from its point's other views of the subset, and per grid point and
    tracked point (G, 2, P) the sum of squares (levels^2) and the count of judged values:
    what the bootstrap over the points resamples. One pass per sigma: the sets (masks over
    the union of their turns), the subsets and the F_tildes share its columns. `turned`:
    the terms turned to a point's facet (`facet_heldout`)."""
    candidates = FACET_CANDIDATES if candidates is None else candidates
    union = tuple(sorted({float(a) for turns in candidates.values() for a in turns}))
    out = [[{} for _ in subsets] for _ in candidates]
    per_point = [[[] for _ in subsets] for _ in candidates]
    for sigma in sigmas:
        sums = facet_sums(
            facet_model(light, sigma, F_tildes[0]), train, train.weight > 0, rotations,
            F_tildes, penalty, shuffle_seed, subsets, union, tuple(candidates.values()), turned,
        )  # fmt: skip
        for grids, kepts, one_set in zip(out, per_point, sums, strict=True):
            for grid, kept, subset in zip(grids, kepts, one_set, strict=True):
                for f, (ssr, count) in zip(F_tildes, subset, strict=True):
                    total = float(np.sum(count))
                    grid[(float(sigma), float(f))] = (
                        math.sqrt(np.sum(ssr) / total) if total else math.nan
                    )
                kept.append(subset)
    return {
        name: [(grid, np.concatenate(kept)) for grid, kept in zip(grids, kepts, strict=True)]
        for name, grids, kepts in zip(candidates, out, per_point, strict=True)
    }


# Resamples of the tracked points (with replacement) for the standard errors of the choice.
BOOTSTRAP_RESAMPLES = 200


def _bootstrap(keys, per_point: np.ndarray, resamples: int, seed: int = 0):
    """The standard errors of `chosen_on_grid`'s (sigma, F_tilde) over the tracked points: the
    grid's RMSE recomputed on `resamples` draws of the points with replacement."""
    counted = per_point[0, 1] > 0
    per_point = per_point[:, :, counted]
    points = per_point.shape[-1]
    if points < 2 or resamples < 2:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    draws = rng.multinomial(points, np.full(points, 1 / points), size=resamples)  # (B, P)
    rmse = np.sqrt((draws @ per_point[:, 0].T) / (draws @ per_point[:, 1].T))  # (B, G)
    picks = np.array([chosen_on_grid(dict(zip(keys, r, strict=True))) for r in rmse])
    return tuple(float(e) for e in np.std(picks, 0, ddof=1))


def _vertex(x: np.ndarray, y: np.ndarray) -> float:
    """The least of a parabola in log x through the least of `y` and its two neighbours
    (kept between them); an end of `x` where the least is there or the parabola opens
    downward."""
    k = int(np.argmin(y))
    if k in (0, len(x) - 1):
        return float(x[k])
    t = np.log(x[k - 1 : k + 2])
    a, b, _ = np.polyfit(t, y[k - 1 : k + 2], 2)
    return float(np.exp(np.clip(-b / (2 * a), t[0], t[2]))) if a > 0 else float(x[k])


def chosen_on_grid(grid: dict, squared: bool = True) -> tuple[float, float]:
    """(sigma, F_tilde) from a grid's calibration RMSE, refined between its neighbours:
    sigma at the vertex of the profile (each sigma's least mean square over F_tilde), then
    F_tilde at that sigma: the vertex over F_tilde on each of the two grid sigmas about it,
    interpolated in log F_tilde and log sigma. The lobe's valley runs along F_tilde ~
    sigma^2 (a height the views resolve better than a width): read at the grid's sigma
    alone, F_tilde jumped with whichever neighbour was lower (the second sinus video's
    turbinate: sigma 0.241 between valleys at (0.2, 0.0136) and (0.3, 0.043), 15.304 and
    15.325 levels; F_tilde 0.0156 +- 0.0115 over resamples of the points, where sigma read
    +- 0.007). The grid's steps (30-50%) are as wide as the halves' check (20%): between
    grid points the halves can agree or not. `squared=False`: the grid's values are
    minimised as they are (a negative log-likelihood), not squared."""
    sigmas = np.unique([k[0] for k in grid])
    F_tildes = np.unique([k[1] for k in grid])
    power = 2 if squared else 1
    square = np.array([[grid.get((a, b), np.inf) ** power for b in F_tildes] for a in sigmas])
    profile = square.min(1)
    sigma = _vertex(sigmas, profile)
    below = int(np.clip(np.searchsorted(sigmas, sigma, side="right") - 1, 0, len(sigmas) - 1))
    above = min(below + 1, len(sigmas) - 1)
    near, far = _vertex(F_tildes, square[below]), _vertex(F_tildes, square[above])
    if above == below or not np.all(np.isfinite(square[[below, above]].min(1))):
        return sigma, _vertex(F_tildes, square[int(np.argmin(profile))])
    t = np.log(sigma / sigmas[below]) / np.log(sigmas[above] / sigmas[below])
    return sigma, float(np.exp((1 - t) * np.log(near) + t * np.log(far)))


def facet_lobe(
    train: TrackSamples,
    test: TrackSamples,
    judged,
    rotations,
    light,
    *,
    sigmas: Sequence[float] = FACET_SIGMAS,
    F_tildes: Sequence[float] = FACET_F_TILDES,
    penalty: float = FACET_PENALTY,
    shuffle_seed: int | None = None,
    refine_steps: int = FACET_REFINE_STEPS,
    halves: bool = True,
    candidates: Mapping[str, Sequence[float]] | None = None,
    unsteady: Sequence[int] = (),
    turned: str = "lobe",
) -> FacetLobe:
    """The lobe about every point's facet: sigma and F_tilde chosen on a grid by the facet
    protocol on `train` (every calibration view judged from the point's other calibration
    views; refined between the grid's points, `chosen_on_grid`), then the `judged` views of
    `test` (M, P) predicted, beside the Lambertian model under the same `light`, without
    and with its own normal chosen the same way.
    `shuffle_seed`: the control (`facet_heldout`), in the grid and the judging alike.
    `refine_steps`: the held-out judgement's facets (for both models) turned by two angles
    from the chosen candidate (`facet_heldout`); the grid's are the candidates as they are.
    `halves`: the grid again on the even and on the odd calibration frames alone (the
    other half's views weighted 0), whose sigmas a determined lobe's agree between
    (`FacetLobe.status`). `candidates`: the candidate facet sets to compare, by name
    (`facet_heldout`'s `across`; default `FACET_CANDIDATES`): the grid on each, and the
    one whose least calibration RMSE is lower used throughout. `unsteady`: frames whose
    brightness the model does not follow (`ctjax.heldout.frame_consistency`'s
    `brightness_off`, by index): the held-out views are judged again without them
    (`FacetLobe.steady`), and a lobe no better there is `no_lobe` (`judged_status`).
    `turned`: `"lobe"` (the facet is the lobe's normal, the diffuse term keeps the
    reconstruction's) or `"both"` (one facet for both terms: the point's normal turned,
    with a lobe about it), in the grid and the judging alike (`facet_heldout`)."""
    if turned not in ("lobe", "both"):
        raise ParameterError(f"facet_lobe turns 'lobe' or 'both', got {turned!r}")
    if not sigmas or not F_tildes:
        raise ParameterError("facet_lobe needs at least one sigma and one F_tilde")
    candidates = FACET_CANDIDATES if candidates is None else dict(candidates)
    if not candidates:
        raise ParameterError("facet_lobe needs at least one set of candidate facets")
    frames = len(np.unique(np.asarray(train.site.frame)[np.asarray(train.weight) > 0]))
    checked = halves and frames >= MIN_FRAMES_FOR_HALVES
    subsets = (None, 0, 1) if checked else (None,)
    grids = _grid(
        train, rotations, light, sigmas, F_tildes, penalty, shuffle_seed, subsets, candidates,
        turned,
    )  # fmt: skip
    candidate_rmse = {name: min(grid[0][0].values()) for name, grid in grids.items()}
    name = min(candidate_rmse, key=candidate_rmse.get)
    across = candidates[name]
    (calibration, per_point), *parts = grids[name]
    sigma, f = chosen_on_grid(calibration)
    stderr = _bootstrap(list(calibration), per_point, BOOTSTRAP_RESAMPLES)
    at_bound = not (min(sigmas) < sigma < max(sigmas) and min(F_tildes) < f < max(F_tildes))
    split = tuple(chosen_on_grid(grid) for grid, _ in parts) if checked else None
    unchecked = frames if halves and not checked else None
    lambertian = facet_model(light, sigma, 0.0)
    own_normal = facet_heldout(
        lambertian, train, train.weight > 0, rotations, penalty=penalty, turned="diffuse",
        across=across,
    )  # fmt: skip
    best = min(calibration.values())  # the grid's least: the refined choice is between points
    gain = 1 - best / own_normal.rmse if own_normal.rmse > 0 else math.nan
    step = views_step(train, rotations)
    status, reasons = facet_status(
        sigma, f, sigmas, F_tildes, gain, split, stderr[0], unchecked, step, stderr[1]
    )
    lobe = facet_heldout(
        facet_model(light, sigma, f), test, judged, rotations, penalty=penalty, turned=turned,
        shuffle_seed=shuffle_seed, refine_steps=refine_steps, across=across,
    )  # fmt: skip
    plain = facet_heldout(lambertian, test, judged, rotations, penalty=penalty, across=(0.0,))
    normals = facet_heldout(
        lambertian, test, judged, rotations, penalty=penalty, turned="diffuse",
        refine_steps=refine_steps, across=across,
    )  # fmt: skip
    status, reasons = judged_status(status, reasons, lobe.rmse, plain.rmse, normals.rmse)
    steady = None
    keep = np.asarray(judged, bool) & ~np.isin(np.asarray(test.site.frame), list(unsteady))
    if keep.any() and keep.sum() < np.sum(judged):
        # Judged again without the test frames whose brightness the model does not follow:
        # each facet adds light where a view is brighter than its point's others.
        parts = (
            facet_heldout(
                facet_model(light, sigma, f), test, keep, rotations, penalty=penalty,
                turned=turned, shuffle_seed=shuffle_seed, refine_steps=refine_steps,
                across=across,
            ),
            facet_heldout(lambertian, test, keep, rotations, penalty=penalty, across=(0.0,)),
            facet_heldout(
                lambertian, test, keep, rotations, penalty=penalty, turned="diffuse",
                refine_steps=refine_steps, across=across,
            ),
        )  # fmt: skip
        rmse, plain_rmse, turned_rmse = (part.rmse for part in parts)
        left_out = sorted({int(i) for i in unsteady})
        steady = {
            "left_out": left_out,
            "heldout_rgb_rmse": rmse,
            "lambertian_same_light_rgb_rmse": plain_rmse,
            "lambertian_turned_normals_rgb_rmse": turned_rmse,
            "ratio": rmse / plain_rmse if plain_rmse > 0 else math.nan,
        }
        status, reasons = judged_status(
            status, reasons, rmse, plain_rmse, turned_rmse,
            where=(
                "on the held-out frames whose brightness the model follows (all but frames "
                f"{', '.join(map(str, left_out))}, by index)"
            ),
            then=(
                "; its gain on all of them lies on frames off in brightness, which a facet "
                "absorbs (a scope's auto-exposure: --effects frame_exposure fits a gain per "
                "frame)"
            ),
        )  # fmt: skip
    control = math.nan  # the same lobe with every point's candidates another point's
    if shuffle_seed is None:
        control = facet_heldout(
            facet_model(light, sigma, f), test, judged, rotations, penalty=penalty, turned=turned,
            shuffle_seed=CONTROL_SEED, refine_steps=refine_steps, across=across,
        ).rmse  # fmt: skip
    return FacetLobe(
        sigma,
        f,
        calibration,
        bool(at_bound and len(sigmas) * len(F_tildes) > 1),
        lobe.rmse,
        plain.rmse,
        normals.rmse,
        lobe.with_facet,
        split,
        gain,
        status,
        reasons,
        stderr,
        name,
        candidate_rmse,
        step,
        control,
        steady,
        turned,
    )


def _undone(summary: dict) -> str:
    """Where the views were judged with the model's image effects undone (`effects_undone`):
    the levels are the radiance's (the first frame's exposure)."""
    effects = summary.get("effects_undone")
    return f" of the radiance ({' and '.join(effects)} undone)" if effects else ""


def _steady_part(steady: dict | None) -> str:
    """The judgement without the frames whose brightness the model does not follow."""
    if not steady:
        return ""
    frames = ", ".join(map(str, steady["left_out"]))
    return (
        f"; without test frames {frames} (by index), off in brightness: "
        f"{steady['ratio']:.3f}x, with its "
        f"own normal {steady['lambertian_turned_normals_rgb_rmse']:.2f} against "
        f"{steady['lambertian_same_light_rgb_rmse']:.2f}"
    )


def facet_lobe_line(summary: dict) -> str:
    """One line for a command's output from `FacetLobe.to_json()`."""
    bound = ", at the end of its grid" if summary["at_bound"] else ""
    return (
        f"a lobe about every point's own facet (sigma {summary['sigma']:.3g} +- "
        f"{summary['sigma_stderr']:.2g}, F_tilde {summary['F_tilde']:.3g} +- "
        f"{summary['F_tilde_stderr']:.2g}, peak F_tilde/sigma^2 {summary['peak']:.3g}, "
        f"chosen on the calibration frames{bound}): held-out RMSE "
        f"{summary['heldout_rgb_rmse']:.2f} levels{_undone(summary)}, {summary['ratio']:.3f}x "
        "Lambert's under "
        f"the same light ({summary['lambertian_same_light_rgb_rmse']:.2f}; with its own normal "
        f"chosen the same way {summary['lambertian_turned_normals_rgb_rmse']:.2f}"
        + (
            ""
            if summary.get("control_ratio") is None
            else f"; with another point's facets {summary['control_ratio']:.3f}x"
        )
        + _steady_part(summary.get("steady_frames"))
        + f"); {100 * summary['views_with_a_facet']:.0f}% of the views took a facet (candidates: "
        f"{summary['candidates']}); status "
        f"{summary['status']}" + "".join(f"; {u['reason']}" for u in summary["undetermined"][:1])
    )


def facets_suggestion(
    status: str, highlight_share: float | None = None, alignment: str | None = None
) -> str | None:
    """What a command says when the frames point at relief finer than the reconstruction:
    most of the held-out residual within 7 px of the highlights (`highlight_share`, at
    least half), or highlights' peaks `scattered` about N = H (`alignment`). Whether or not
    the lobe about the reconstruction's normals was found (`status`): on the SCARED da Vinci
    sequences a found one predicts the test frames at 0.94-1.0x Lambert's RMSE under the
    same light and leaves about 80% of its residual there; a lobe about each point's facet
    0.71-0.79x (docs: real endoscopic video). None where nothing points there."""
    near = highlight_share is not None and highlight_share >= 0.5
    if not near and alignment != "scattered":
        return None
    why = (
        f"{100 * highlight_share:.0f}% of the held-out residual lies within 7 px of the highlights"
        if near
        else "the highlights' peaks scatter about N = H (relief finer than the shape)"
    )
    lobe = (
        "though the lobe about these normals is found"
        if status == "successful"
        else f"and the lobe about these normals is {status}"
    )
    return (
        f"{why} {lobe}: a lobe about each tracked point's own facet, its normal read from "
        "the views where it shone, may be what the frames show"
    )
