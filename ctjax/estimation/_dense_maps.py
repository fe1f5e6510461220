"""Every pixel's albedo given the fitted BRDF: the dense albedo maps, and the residual
images the held-out protocol reads from them.

The fit (`ctjax.estimation._branch_and_bound_map`) follows a few thousand surface points; once its
global lobes are known, each pixel of each frame is a surface point whose albedo is the
weighted least-squares one over the frames that see it, in closed form per channel. Each
frame's lobes are rendered once at its pixel centres and sampled bilinearly where a point
lands, as the image is (`ctjax._tracks` says when a point counts as seen).
"""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np

from .._programs import persistent_jit
from .._render import render_columns
from .._tracks import (
    DEFAULT_NEIGHBOURS,
    DEFAULT_TOLERANCE,
    FrameData,
    partners,
    sample_image,
    sight,
    sight_own,
    world_points,
)
from ..effects._effect import Site, apply_effects, undo_effects
from ..lights import AbstractLight
from ..lights._point import default_light

# Albedo maps are left NaN where the diffuse column is below this (N.L / pi in every view
# below ~0.05 / pi): the albedo would be noise divided by nearly 0.
MIN_COSINE = 0.05
# Pixels whose albedo is estimated at once (bounds memory at 1080p).
_MAP_CHUNK = 1 << 17


@persistent_jit
def _frame_columns(brdf, light, camera, normals, depth):
    """One frame's lobes for unit weights at its pixel centres, (H, W, K) float32 (0 where
    it has no geometry): K planes per pixel, the least a frame's model can be kept in."""
    return render_columns(brdf, light, camera, normals, depth).astype(jnp.float32)


def _albedo_of(
    capture, data, shading, weights, per_point, pieces, count, among, tolerance, effects=()
):
    """Albedo (N, 3; NaN where not estimated) and view count (N,) of the pixels of
    `pieces`, [(frame index, rows, cols)], from all the frames that see them (see
    `albedo_maps`), and each pixel's residual in its own frame (N, 3) under the albedo of
    the other views alone (NaN where they have none); N pixels in all, in the pieces' order.
    `shading(f)` is frame f's `_frame_columns`: a point's model in another view is their
    bilinear sample, as its value is the image's. Each frame is sighted once for every
    piece that looks for its points there (a summary's few thousand pixels per frame were
    mostly NumPy's per-call overhead when sighted frame by frame). `effects`: image effects
    after the lobes (a camera response...): undone on the measured values (their `inverse`),
    and the own residual is the image's (the effects applied to the prediction)."""
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

    def add(where, obs, columns, frame):  # frame's observations of the pixels `where`
        seen = obs.weight > 0  # some channel counts
        columns = np.where(seen[:, None], columns.reshape(len(seen), -1), 0.0)  # (N, K)
        a, rest = columns[:, per_point], columns[:, global_] @ weights[global_]
        # Per channel: a channel clipped in this view says nothing of that channel's albedo.
        weight = obs.weight[:, None] * obs.channel_seen
        linear = _undone(effects, obs.values, obs.u, obs.v, frame)
        contribution = a[:, None] * (linear - rest) * weight
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
                found = add(
                    part, sight_own(data[index], rows, cols), shading(other)[rows, cols], other
                )
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
            add(where, obs, sample_image(shading(other), obs.u, obs.v), other)
    enough = (cosine[:, None] > (MIN_COSINE / np.pi) ** 2) & (denominator > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        albedo = np.where(enough, np.maximum(numerator / denominator, 0), np.nan)
        # The own observation against the albedo of the other views alone.
        a, rest, values, weight, own_numerator = own
        others = denominator - (a * a)[:, None] * weight
        enough_others = enough & (others > 1e-3 * denominator)
        albedo_others = np.maximum((numerator - own_numerator) / others, 0)
        predicted = rest + a[:, None] * albedo_others
        own_frame = np.concatenate([np.full(len(rows), i) for i, rows, _ in pieces])
        own_u = np.concatenate([cols for _, _, cols in pieces]).astype(float)
        own_v = np.concatenate([rows for _, rows, _ in pieces]).astype(float)
        predicted = _applied(effects, np.nan_to_num(predicted), own_u, own_v, own_frame)
        residual = values - predicted
        residual = np.where(enough_others & (weight > 0), residual, np.nan)
    return albedo, seen_count, residual


def albedo_maps(
    capture,
    brdf,
    light: AbstractLight | None = None,
    *,
    per_point: int = 0,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
    tolerance: float | None = None,
    frames=None,
    among=None,
    dtype=None,
    effects=(),
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
    `effects`: image effects undone on the measured values first (a frame's exposure).
    """
    camera = capture.camera
    maps, views = [], []
    for _, rows, cols, albedo, seen_count, _ in _frames_of(
        capture,
        brdf,
        light,
        frames,
        per_point,
        neighbours,
        tolerance,
        dtype,
        among,
        effects=effects,
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
    light: AbstractLight | None = None,
    *,
    stride: int,
    per_point: int = 0,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
    dtype=None,
    effects=(),
):
    """`albedo_maps` at every frame's pixels with geometry on every `stride`-th row and
    column: per frame, their albedo (N, 3; NaN where not estimated) and view count (N,).
    A summary of the maps (median, coverage) at 1 / stride^2 of their cost."""
    return [
        (albedo, seen_count)
        for _, _, _, albedo, seen_count, _ in _frames_of(
            capture,
            brdf,
            light,
            None,
            per_point,
            neighbours,
            None,
            dtype,
            stride=stride,
            effects=effects,
        )
    ]


def _sites(u, v, frame, n: int) -> Site:
    return Site((jnp.asarray(u), jnp.asarray(v)), jnp.broadcast_to(jnp.asarray(frame), (n,)))


def _undone(effects, values: np.ndarray, u, v, frame) -> np.ndarray:
    """Measured values (N, 3), recorded at pixels (u, v) of `frame` (an index, or one per
    value), with the image effects undone, last first."""
    if not effects:
        return values
    undo = jax.vmap(lambda x, site: undo_effects(effects, x, site))
    return np.asarray(undo(jnp.asarray(values), _sites(u, v, frame, len(values))))


def _applied(effects, values: np.ndarray, u, v, frame) -> np.ndarray:
    """Linear values (N, 3) with the image effects applied, in order (as `_undone`)."""
    if not effects:
        return values
    apply = jax.vmap(lambda x, site: apply_effects(effects, x, site))
    return np.asarray(apply(jnp.asarray(values), _sites(u, v, frame, len(values))))


def _frames_of(
    capture,
    brdf,
    light,
    frames,
    per_point,
    neighbours,
    tolerance,
    dtype,
    among=None,
    stride=1,
    effects=(),
):
    """For each frame of `frames` (all when None): its pixels with geometry (rows, cols;
    on every `stride`-th row and column) and their albedo, view count and own residual
    (`_albedo_of`), in batches of at most `_MAP_CHUNK` pixels (bounded memory at 1080p;
    several frames' at once where they are few, as a summary's)."""
    light = default_light(light)
    dtype = jax.dtypes.canonicalize_dtype(np.float64 if dtype is None else dtype)
    tolerance = DEFAULT_TOLERANCE if tolerance is None else tolerance
    camera = capture.camera
    level = np.asarray(capture.saturation, np.float32)  # the channels' ceilings
    data = [FrameData.of(f, level) for f in capture.frames]
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
        out = _albedo_of(
            capture, data, shading, weights, per_point, batch, count, among, tolerance, effects
        )
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
    light: AbstractLight | None = None,
    frames=None,
    *,
    per_point: int = 0,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
    dtype=None,
    effects=(),
):
    """Residual images (measured - model; H, W, 3; linear units, NaN where not usable) of
    `frames` (all by default) under the albedo map, each pixel against the albedo fitted to
    the OTHER frames that see it (`albedo_maps` without its own view): its own noise is then
    not partly fitted away (which made the noise floor 14% low), and the other views' noise,
    averaged and interpolated, adds little. NaN where no other view counts. `effects`: the
    model's image effects (undone on the measurements for the albedo, applied to the
    prediction)."""
    camera = capture.camera
    out = []
    for _, rows, cols, _, _, residual in _frames_of(
        capture, brdf, light, frames, per_point, neighbours, None, dtype, effects=effects
    ):
        image = np.full((camera.height, camera.width, 3), np.nan)
        image[rows, cols] = residual
        out.append(image)
    return out
