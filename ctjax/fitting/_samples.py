"""Pixel samples of a capture: where the model is compared with the measurements."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._camera import Camera
from .._errors import CtjaxError
from .._typing import Array, Float, Int
from .._vector import Vec3
from ..io import Capture


class PixelSamples(eqx.Module):
    """N pixels: camera-frame point (mm) and unit normal, pixel (u, v), measured linear RGB
    (1.0 = 8-bit level 255), and the index of the frame and (row, col) they come from."""

    point: Vec3
    normal: Vec3
    pixel: tuple[Float[Array, " N"], Float[Array, " N"]]
    values: Float[Array, "N 3"]
    frame: Int[Array, " N"]
    row: Int[Array, " N"]
    col: Int[Array, " N"]

    def __len__(self) -> int:
        return self.values.shape[0]


def usable_mask(frame, saturation_level: float = 1.0) -> np.ndarray:
    """Pixels with geometry (finite positive depth and normal) and no clipped channel."""
    if frame.depth is None or frame.normals is None:
        raise CtjaxError(f"frame {frame.name}: needs depth (and normals) to compare the model")
    return frame.geometry_mask & np.all(frame.image < saturation_level, axis=-1)


def capture_samples(
    capture: Capture,
    frames: list[int],
    *,
    max_samples: int | None = None,
    seed: int = 0,
    dtype=None,
) -> PixelSamples:
    """The usable pixels of `frames` (indices into the capture), optionally a random
    subset of at most `max_samples` (deterministic for a given seed)."""
    if dtype is None:
        dtype = jax.dtypes.canonicalize_dtype(np.float64)
    camera: Camera = capture.camera
    parts = []
    for index in frames:
        frame = capture.frames[index]
        rows, cols = np.nonzero(usable_mask(frame))
        parts.append((index, rows, cols))
    total = sum(len(r) for _, r, _ in parts)
    if total == 0:
        raise CtjaxError(
            f"{capture.root}: no usable pixel (geometry and unsaturated) in frames {frames}"
        )
    keep = None
    if max_samples is not None and total > max_samples:
        keep = np.sort(np.random.default_rng(seed).choice(total, max_samples, replace=False))
    index = np.concatenate([np.full(len(r), i) for i, r, _ in parts])
    rows = np.concatenate([r for _, r, _ in parts])
    cols = np.concatenate([c for _, _, c in parts])
    if keep is not None:
        index, rows, cols = index[keep], rows[keep], cols[keep]
    depth = np.concatenate(
        [capture.frames[i].depth[r, c] for i, r, c in _groups(index, rows, cols)]
    )
    normals = np.concatenate(
        [capture.frames[i].normals[r, c] for i, r, c in _groups(index, rows, cols)]
    )
    values = np.concatenate(
        [capture.frames[i].image[r, c] for i, r, c in _groups(index, rows, cols)]
    )
    u, v = cols.astype(np.float64), rows.astype(np.float64)
    x = depth * (u - float(camera.cx)) / float(camera.fx)
    y = depth * (v - float(camera.cy)) / float(camera.fy)
    as_array = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    return PixelSamples(
        Vec3(as_array(x), as_array(y), as_array(depth)),
        Vec3.from_array(as_array(normals)),
        (as_array(u), as_array(v)),
        as_array(values),
        jnp.asarray(index),
        jnp.asarray(rows),
        jnp.asarray(cols),
    )


def _groups(index, rows, cols):
    """(frame, rows, cols) runs, in the order of `index` (which is sorted by frame)."""
    for i in np.unique(index):
        mask = index == i
        yield i, rows[mask], cols[mask]
