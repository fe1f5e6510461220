"""Shading samples: the measured RGB of pixels whose geometry and light are known."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._camera import Camera
from .._errors import ParameterError
from .._typing import Array, Float
from .._vector import Vec3


class ShadingSamples(eqx.Module):
    """N pixels: unit normal, light and view directions (camera frame), the irradiance
    factor of the light there, and the measured linear RGB (1.0 = 8-bit level 255)."""

    normal: Vec3
    light: Vec3
    view: Vec3
    irradiance: Float[Array, " N"]
    values: Float[Array, "N 3"]

    def __check_init__(self):
        n = self.values.shape[0]
        if self.values.ndim != 2 or self.values.shape[1] != 3:
            raise ParameterError(f"sample values must be (N, 3) RGB, got {self.values.shape}")
        for name in ("normal", "light", "view"):
            for part in (getattr(self, name).x, getattr(self, name).y, getattr(self, name).z):
                if jnp.shape(part) != (n,):
                    raise ParameterError(f"sample {name} must have {n} entries per component")
        if jnp.shape(self.irradiance) != (n,):
            raise ParameterError(f"sample irradiance must have shape ({n},)")

    def __len__(self) -> int:
        return self.values.shape[0]


def view_directions(camera: Camera, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Unit directions (N, 3) from the surface point seen at each pixel towards the camera.

    Along the pixel's ray, so they do not need depth.
    """
    ray = np.stack(
        [
            (cols - float(camera.cx)) / float(camera.fx),
            (rows - float(camera.cy)) / float(camera.fy),
            np.ones(rows.shape),
        ],
        axis=-1,
    )
    return -ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def colocated_samples(
    camera: Camera, image: np.ndarray, normals: np.ndarray, mask: np.ndarray, dtype=None
) -> ShadingSamples:
    """Samples of the pixels in `mask` under the paper's light: L = V, unit irradiance.

    `dtype` defaults to JAX's default float (float64 when x64 is enabled, as the CLI does).
    """
    if dtype is None:
        dtype = jax.dtypes.canonicalize_dtype(np.float64)
    rows, cols = np.nonzero(mask)
    view = view_directions(camera, rows.astype(float), cols.astype(float)).astype(dtype)
    normal = normals[rows, cols].astype(dtype)
    v = Vec3.from_array(jnp.asarray(view))
    return ShadingSamples(
        Vec3.from_array(jnp.asarray(normal)),
        v,
        v,
        jnp.ones(len(rows), dtype),
        jnp.asarray(image[rows, cols], dtype),
    )


def concatenate(samples: list[ShadingSamples]) -> ShadingSamples:
    return jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *samples)


def paper_coefficients(samples: ShadingSamples):
    """The per-pixel coefficients of the paper's eq. (4), as NumPy arrays (N,):

    `I = a rho + b F sigma^-2 exp(-c / sigma^2)`, a = (N.L) E / pi,
    b = E / (pi (N.L)(N.V) cos^4 alpha), c = tan^2 alpha, E the irradiance factor.
    """
    n, l, v = (
        np.asarray(getattr(samples, k).to_array(), np.float64) for k in ("normal", "light", "view")
    )
    irradiance = np.asarray(samples.irradiance, np.float64)
    half = l + v
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    n_dot_l, n_dot_v = np.sum(n * l, -1), np.sum(n * v, -1)
    cos2 = np.sum(n * half, -1) ** 2
    a = irradiance * n_dot_l / np.pi
    b = irradiance / (np.pi * n_dot_l * n_dot_v * cos2 * cos2)
    c = (1 - cos2) / cos2
    return a, b, c
