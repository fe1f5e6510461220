import equinox as eqx
import jax.numpy as jnp

from .._convert import as_float, check_positive, check_shape
from .._typing import Array, Float, Scalar
from ._distribution import AbstractDistribution


def beckmann(cos_alpha: Scalar, sigma: Scalar) -> Scalar:
    """The paper's eq. (2), `exp(-tan^2 a / s^2) / (s^2 cos^4 a)`.

    Written with one division per sample (this is the renderer's hot loop). For small sigma
    the exponential underflows to exactly 0 (also in float64): the result is then 0, never
    0 * inf, because the prefactor `1 / (s^2 cos^4 a)` stays finite for sigma >= 1e-9 and
    cos a >= 1e-6. Estimators must still guard the resulting all-zero design columns.
    """
    inv_cos2 = 1 / (cos_alpha * cos_alpha)
    inv_sigma2 = 1 / (sigma * sigma)
    tan2 = jnp.maximum(inv_cos2 - 1, 0)
    return jnp.exp(-tan2 * inv_sigma2) * (inv_sigma2 * inv_cos2 * inv_cos2)


class Beckmann(AbstractDistribution):
    """Beckmann distribution of the paper, eq. (2): `exp(-tan^2 a / s^2) / (s^2 cos^4 a)`.

    **Arguments:**

    - `sigma`: RMS slope of the microfacets (roughness), > 0. The paper searches [1e-5, 1].
    """

    sigma: Float[Array, ""] = eqx.field(converter=as_float)

    def __check_init__(self):
        check_shape("Beckmann", "sigma", self.sigma, ())
        check_positive("Beckmann", "sigma", self.sigma)

    def __call__(self, cos_alpha: Scalar) -> Scalar:
        return beckmann(cos_alpha, self.sigma)
