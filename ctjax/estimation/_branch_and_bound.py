"""The paper's branch-and-bound over the nonlinear parameters, as a batched zooming grid.

The paper (section 4) splits the admissible interval of sigma into sub-intervals, solves
the convex subproblem at each centre, keeps the best sub-interval and repeats until it is
shorter than a threshold ([1e-5, 1] down to 1e-3). Here each level evaluates a whole grid of
centres at once (`vmap`), keeps the best `candidates` sub-intervals (more than one, so that a
second basin of the cost is not lost to a coarse first level), and zooms into each, all
inside one compiled function: the first level tiles the box, and every later level (the same
shape: `candidates` boxes of the zoom grid) is traced once and looped (`lax.scan`). Several
nonlinear parameters (e.g. two roughness scales) use a tensor grid.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._typing import Array, Float, Scalar


class GridSearchResult(eqx.Module):
    """The best parameters found, their cost, and half the final grid spacing (the
    uncertainty of the search itself, per parameter)."""

    params: Float[Array, " D"]
    cost: Scalar
    half_width: Float[Array, " D"]
    evaluations: int = eqx.field(static=True)


def zoom_levels(
    lo, hi, tolerance: float, grid: int, zoom: int = 2, zoom_grid: int | None = None
) -> tuple[int, float]:
    """Levels until the grid spacing is below `tolerance`, and that final spacing.

    Level 1 spaces `grid` centres over the whole box; each further level spaces `zoom_grid`
    (default `grid`) centres over a box `zoom` spacings wide around each kept centre, so the
    spacing shrinks by zoom_grid / zoom.
    """
    zoom_grid = grid if zoom_grid is None else zoom_grid
    spacing = max(float(h) - float(l) for l, h in zip(lo, hi, strict=True)) / grid
    levels = 1
    while spacing > tolerance:
        spacing *= zoom / zoom_grid
        levels += 1
    return levels, spacing


def _local_minima(costs: Float[Array, "M G"], dims: int, grid: int):
    """Grid points no worse than their neighbours along every axis, per candidate box."""
    shaped = costs.reshape(costs.shape[0], *([grid] * dims))
    minimum = jnp.ones(shaped.shape, bool)
    for axis in range(1, dims + 1):
        padded = jnp.pad(
            shaped, [(0, 0)] * axis + [(1, 1)] + [(0, 0)] * (dims - axis), constant_values=jnp.inf
        )
        before = jax.lax.slice_in_dim(padded, 0, grid, axis=axis)
        after = jax.lax.slice_in_dim(padded, 2, grid + 2, axis=axis)
        minimum = minimum & (shaped <= before) & (shaped <= after)
    return minimum.reshape(costs.shape)


def _looped(level, count: int, starts, widths, best):
    """`count` applications of `level(starts, widths, best) -> (starts, widths, best,
    spacing)`, traced once and looped (`lax.scan`), and the last spacing."""

    def body(carry, _):
        *carry, spacing = level(*carry)
        return tuple(carry), spacing

    (starts, widths, best), spacings = jax.lax.scan(body, (starts, widths, best), length=count)
    return starts, widths, best, spacings[-1]


def grid_search(
    cost: Callable[[Float[Array, " D"]], Scalar],
    lo,
    hi,
    *,
    tolerance: float = 1e-3,
    grid: int = 32,
    candidates: int = 4,
    zoom: int = 2,
    zoom_grid: int | None = None,
    dtype=None,
    batch: int | None = None,
    coarse: Callable[[Float[Array, " D"]], Scalar] | None = None,
    coarse_levels: int = 1,
) -> GridSearchResult:
    """Minimise `cost(params)` over the box [lo, hi] by zooming grids (see module doc).

    `cost` maps a (D,) parameter vector to a scalar and is `vmap`ped over the grid; it must
    return finite values or +inf (non-finite values are treated as +inf). Each level keeps
    the `candidates` best grid points, local minima first (one per basin before a second
    point of the same basin), and searches `zoom` sub-intervals around each at the next level
    (`candidates=1, zoom=1` is exactly the paper's BnB, which zooms into the best
    sub-interval). `zoom_grid` (default `grid`) points per axis at the levels after the
    first: the first level's grid finds the basins, the later ones only narrow a box `zoom`
    spacings wide. D = 1 or 2 in practice: a later level costs `candidates * zoom_grid^D`
    evaluations.
    `batch` evaluates the grid `batch` points at a time (`jax.lax.map`) instead of all at
    once: for costs over many samples, whose batched intermediates would not stay in cache.
    `coarse` (default `cost`) is what the first `coarse_levels` levels evaluate: a cheaper
    cost with the same basins (e.g. `cost` on a subset of the samples), since those levels
    only pick the boxes the later ones narrow (at least the last level evaluates `cost`, and
    the result's cost is the best of the levels that did).
    """
    # The box is configuration (it sets the number of levels): concrete, not traced.
    lo = np.atleast_1d(np.asarray(lo, float))
    hi = np.atleast_1d(np.asarray(hi, float))
    dims = lo.shape[0]
    zoom_grid = grid if zoom_grid is None else zoom_grid
    levels, _ = zoom_levels(lo, hi, tolerance, grid, zoom, zoom_grid)
    dtype = jax.dtypes.canonicalize_dtype(float if dtype is None else dtype)
    lo, hi = jnp.asarray(lo, dtype), jnp.asarray(hi, dtype)

    def unit_grid(points: int):
        offsets = (jnp.arange(points, dtype=dtype) + 0.5) / points  # centres in [0, 1]
        return jnp.stack(jnp.meshgrid(*([offsets] * dims), indexing="ij"), -1).reshape(-1, dims)

    def evaluate(cost, centres):  # (M, G^D, D) -> (M, G^D)
        def safe_cost(params):
            value = cost(params)
            return jnp.where(jnp.isfinite(value), value, jnp.inf)

        if batch is None:
            return jax.vmap(jax.vmap(safe_cost))(centres)
        flat = centres.reshape(-1, dims)
        return jax.lax.map(safe_cost, flat, batch_size=batch).reshape(centres.shape[:2])

    def search_level(starts, widths, points, best, minima, cost=cost):
        """Evaluate `points`^D centres in each box (lower corners `starts` (M, D), size
        `widths`), keep the best, and return the next level's boxes around the candidates."""
        spacing = widths / points
        centres = starts[:, None, :] + unit_grid(points)[None, :, :] * widths  # (M, G^D, D)
        costs = evaluate(cost, centres)
        flat_centres, flat_costs = centres.reshape(-1, dims), costs.reshape(-1)
        is_minimum = minima(costs).reshape(-1)
        order = jnp.lexsort((flat_costs, ~is_minimum))[: min(candidates, flat_costs.shape[0])]
        level_best = jnp.argmin(flat_costs)
        improved = flat_costs[level_best] < best[1]
        best = (
            jnp.where(improved, flat_centres[level_best], best[0]),
            jnp.where(improved, flat_costs[level_best], best[1]),
        )
        # Zoom: a box `zoom` sub-intervals wide around each kept centre, inside [lo, hi].
        widths = zoom * spacing
        return jnp.clip(flat_centres[order] - widths / 2, lo, hi - widths), widths, best, spacing

    best = ((lo + hi) / 2, jnp.asarray(jnp.inf, dtype))
    # Level 1 tiles the box; every later level has the same shape (`candidates` boxes of
    # `zoom_grid`^D points): traced once and looped.
    minima = lambda points: lambda c: _local_minima(c, dims, points)  # noqa: E731
    # The first `coarse_levels` levels (all but the last at most) evaluate `coarse`.
    coarse_levels = 0 if coarse is None else min(coarse_levels, levels - 1)
    first = coarse if coarse_levels else cost
    starts, widths, best, spacing = search_level(
        lo[None, :], hi - lo, grid, best, minima(grid), first
    )
    kept = min(candidates, grid**dims)

    # A later level's search, as `_looped` applies it.
    zoom_level = lambda c: lambda s, w, b: search_level(s, w, zoom_grid, b, minima(zoom_grid), c)  # noqa: E731
    if coarse_levels > 1:
        starts, widths, best, spacing = _looped(
            zoom_level(coarse), coarse_levels - 1, starts, widths, best
        )
    if coarse_levels:  # its costs are not comparable with `cost`'s
        best = (best[0], jnp.asarray(jnp.inf, dtype))
    if levels > max(coarse_levels, 1):
        count = levels - max(coarse_levels, 1)
        _, _, best, spacing = _looped(zoom_level(cost), count, starts, widths, best)
    evaluations = grid**dims + (levels - 1) * kept * zoom_grid**dims
    return GridSearchResult(best[0], best[1], spacing / 2, evaluations)
