"""The light field's data and its propagation from S (paper section 5): every calibration
frame's observations at every pixel, batches of per-pixel problems, and the band-by-band
solve outwards from the boundary L = V on the specular set S.
"""

import dataclasses
import itertools

import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from .._vector import Vec3
from ..observations import Observations
from ._field_problem import PixelProblem

# Propagation: pixels are solved in bands of distance (px) from S, each band starting from
# the solved pixels inside it; widths double, so a 640x480 image takes ~10 batched solves.
_FIRST_BAND_PX = 3.0
# Every batched solve has this many pixels (the last batch padded): one compilation.
_BATCH = 4096


@dataclasses.dataclass
class FieldObservations:
    """Every calibration frame's data at every pixel, (H, W, F, ...), and the view (H, W, 3)."""

    view: np.ndarray
    normal: np.ndarray  # (H, W, F, 3), 0 where unobserved
    values: np.ndarray  # (H, W, F, 3)
    weight: np.ndarray  # (H, W, F)
    irradiance: np.ndarray  # (H, W, F)
    albedo: np.ndarray  # (H, W, F, 3): the surface point's, with an albedo map; else 0

    def with_albedo(self, maps: list[np.ndarray]) -> "FieldObservations":
        """These observations with each frame's albedo map (H, W, 3); a pixel's view
        whose albedo is not estimated (NaN) is not used."""
        albedo = np.stack(maps, axis=2)
        known = np.all(np.isfinite(albedo), axis=-1)
        return dataclasses.replace(
            self,
            albedo=np.nan_to_num(albedo).astype(self.values.dtype),
            weight=self.weight * known,
        )


def field_observations(obs: Observations, frames: list[int], falloff, dtype) -> FieldObservations:
    """Every frame of `frames` at every pixel of S-bar (usable, not specular, not saturated),
    with the irradiance factor of the light's `falloff` there."""
    normal, values, weight, irradiance = [], [], [], []
    for index in frames:
        frame, sets = obs.frames[index], obs.sets[index]
        observed = obs.usable[index] & ~sets.specular & ~sets.saturated
        normal.append(np.where(observed[..., None], np.nan_to_num(frame.normals), [0, 0, -1]))
        values.append(np.where(observed[..., None], frame.image, 0))
        weight.append(observed)
        point = np.where(observed[..., None], np.nan_to_num(obs.points(index)), [0, 0, 1.0])
        factor = np.ones(observed.shape)
        for effect in falloff:
            factor = factor * np.asarray(effect(Vec3.from_array(point)))
        irradiance.append(factor)
    stack = lambda parts: np.stack(parts, axis=2).astype(dtype)  # noqa: E731
    return FieldObservations(
        obs.view.astype(dtype),
        stack(normal),
        stack(values),
        stack(weight),
        stack(irradiance),
        np.zeros_like(stack(values)),
    )


def _problems(obs: FieldObservations, index, start, prior) -> PixelProblem:
    """A batch of pixels (flat indices), padded to `_BATCH` by repeating the last."""
    index = np.concatenate([index, np.full(_BATCH - len(index), index[-1])])
    height, width = obs.view.shape[:2]
    flat = lambda a: a.reshape(height * width, *a.shape[2:])[index]  # noqa: E731
    vec = lambda a: Vec3.from_array(jnp.asarray(a))  # noqa: E731
    return PixelProblem(
        vec(flat(obs.view)),
        vec(flat(obs.normal)),
        jnp.asarray(flat(obs.values)),
        jnp.asarray(flat(obs.weight)),
        jnp.asarray(flat(obs.irradiance)),
        jnp.asarray(flat(obs.albedo)),
        vec(start[index].astype(obs.view.dtype)),
        vec(prior[index].astype(obs.view.dtype)),
    )


def solve_batches(obs, index, start, prior, brdf, solve):
    """Solve the pixels `index` (flat) in batches by `solve(problems, brdf)`; start and prior
    are (H*W, 3)."""
    out = {k: [] for k in ("direction", "result", "steps", "rmse")}
    for lo in range(0, len(index), _BATCH):
        part = index[lo : lo + _BATCH]
        solution = solve(_problems(obs, part, start, prior), brdf)
        for key in out:
            out[key].append(np.asarray(getattr(solution, key))[: len(part)])
    return {k: np.concatenate(v) for k, v in out.items()}


def neighbour_mean(directions: np.ndarray, solved: np.ndarray, radius: int = 2) -> np.ndarray:
    """Per pixel, the normalised mean of the solved directions within `radius` px, or the
    nearest solved pixel's direction where none is that close. (H, W, 3)."""
    size = 2 * radius + 1
    weight = ndimage.uniform_filter(solved.astype(float), size, mode="constant")
    total = np.stack(
        [
            ndimage.uniform_filter(np.where(solved, directions[..., k], 0), size, mode="constant")
            for k in range(3)
        ],
        -1,
    )
    _, (near_r, near_c) = ndimage.distance_transform_edt(~solved, return_indices=True)
    nearest = directions[near_r, near_c]
    mean = np.where(weight[..., None] > 1e-9, total, nearest)
    return mean / np.linalg.norm(mean, axis=-1, keepdims=True)


def propagate(obs: FieldObservations, boundary, todo, brdf, solve) -> np.ndarray:
    """Directions (H, W, 3) solved outwards from L = V on S (`boundary`) over the pixels
    `todo`, in bands of doubling width, each band started from its solved neighbours (NaN
    where not solved)."""
    distance = ndimage.distance_transform_edt(~boundary)
    directions = np.where(boundary[..., None], obs.view, np.nan)
    solved = boundary.copy()
    edges = [0.0, _FIRST_BAND_PX]
    while edges[-1] < distance[todo].max():
        edges.append(2 * edges[-1])
    for lo, hi in itertools.pairwise(edges):
        band = todo & (distance > lo) & (distance <= hi)
        if not band.any():
            continue
        start = neighbour_mean(np.nan_to_num(directions), solved).reshape(-1, 3)
        index = np.flatnonzero(band)
        out = solve_batches(obs, index, start, start, brdf, solve)
        directions.reshape(-1, 3)[index] = out["direction"]
        solved |= band
    return directions
