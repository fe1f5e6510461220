import equinox as eqx
import jax.numpy as jnp

from .._convert import POSITIVE, as_float, check_positive, check_shape, named
from .._typing import Array, Float, Scalar
from ._distribution import AbstractDistribution

# Below this exponent D is exactly 0 for our purposes (e^-80 ~ 1e-35; float32 flushes near
# e^-87). Cutting there keeps the backward pass free of 0 * inf.
_UNDERFLOW_EXPONENT = -80.0


def beckmann(cos_alpha: Scalar, sigma: Scalar) -> Scalar:
    """The paper's eq. (2), `exp(-tan^2 a / s^2) / (s^2 cos^4 a)`.

    Written with one division per sample (this is the renderer's hot loop). Where the
    exponential underflows (small sigma, or alpha near 90 degrees) the result is exactly 0
    with a zero gradient: without the cut, the huge prefactor `1 / (s^2 cos^4 a)` times the
    caller's `1 / (N.L)(N.V)` overflows in the backward pass and meets the 0 as 0 * inf.
    Estimators must still guard the resulting all-zero design columns.
    """
    inv_cos2 = 1 / (cos_alpha * cos_alpha)
    inv_sigma2 = 1 / (sigma * sigma)
    exponent = -jnp.maximum(inv_cos2 - 1, 0) * inv_sigma2
    negligible = exponent < _UNDERFLOW_EXPONENT
    density = jnp.exp(jnp.where(negligible, 0, exponent)) * (inv_sigma2 * inv_cos2 * inv_cos2)
    return jnp.where(negligible, 0, density)


class Beckmann(AbstractDistribution):
    """Beckmann distribution of the paper, eq. (2): `exp(-tan^2 a / s^2) / (s^2 cos^4 a)`.

    **Arguments:**

    - `sigma`: RMS slope of the microfacets (roughness), > 0. The paper searches [1e-5, 1].
    """

    sigma: Float[Array, ""] = eqx.field(converter=as_float, metadata=named("sigma", POSITIVE))

    def __check_init__(self):
        check_shape("Beckmann", "sigma", self.sigma, ())
        check_positive("Beckmann", "sigma", self.sigma)

    def __call__(self, cos_alpha: Scalar) -> Scalar:
        return beckmann(cos_alpha, self.sigma)
