"""Fitting BRDFs to measured samples (L, V, value), e.g. ALTA files."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._numerics import COSINE_FLOOR
from .._typing import Array, Float
from .._vector import Vec3
from ..io import MeasuredBRDF


class DirectionSamples(eqx.Module):
    """N measurements of a BRDF: unit normal, light and view (surface frame), values (N, C)."""

    normal: Vec3
    light: Vec3
    view: Vec3
    values: Float[Array, "N C"]
    cosine_factor: bool = eqx.field(static=True, default=False)

    def __len__(self) -> int:
        return self.values.shape[0]


def measured_samples(data: MeasuredBRDF, dtype=jnp.float64) -> DirectionSamples:
    """`DirectionSamples` of measured data (normal +z)."""
    n = len(data)
    normal = np.tile(np.array([0.0, 0.0, 1.0]), (n, 1))
    as_vec = lambda a: Vec3.from_array(jnp.asarray(a, dtype))  # noqa: E731
    return DirectionSamples(
        as_vec(normal),
        as_vec(data.light),
        as_vec(data.view),
        jnp.asarray(data.values, dtype),
        data.param_out == "INV_STERADIAN_COSINE_FACTOR",
    )


def _per_steradian(sample, radiance):
    """Lobes return radiance (BRDF times N.L); BRDF data want the BRDF itself."""
    if sample.cosine_factor:
        return radiance
    return radiance / jnp.maximum(sample.normal @ sample.light, COSINE_FLOOR)


def brdf_predict(brdf, sample) -> Float[Array, " C"]:
    """`Predict` for `DirectionSamples`: the BRDF (1/sr, or times cos theta_l) per channel,
    truncated to the data's channels."""
    value = _per_steradian(sample, brdf.radiance(sample.normal, sample.light, sample.view))
    return value[: sample.values.shape[-1]]


def brdf_columns(brdf, sample):
    """Linear design row for `DirectionSamples` and a BRDF."""
    return _per_steradian(sample, brdf.columns(sample.normal, sample.light, sample.view))
