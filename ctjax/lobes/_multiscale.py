import equinox as eqx
import jax
import jax.numpy as jnp

from .._convert import POSITIVE, as_float, check_positive
from .._errors import ParameterError
from .._typing import Array, Float, Scalar
from ._beckmann import beckmann
from ._distribution import AbstractDistribution


class MultiScaleBeckmann(AbstractDistribution):
    """Several roughness scales, paper eq. (3): `D = sum_p w_p D(sigma_p)`, `sum_p w_p = 1`.

    The mixing weights are normalised here, so any positive weights may be given. (For
    estimation with free weights, use one `Specular` lobe per scale instead: their weights
    `F_tilde * w_p` are then linear and solved in closed form.)

    **Arguments:**

    - `sigmas`: roughness of each scale, > 0, shape (P,).
    - `mix`: mixing weight of each scale, >= 0, shape (P,).
    """

    sigmas: Float[Array, " P"] = eqx.field(converter=as_float, metadata=POSITIVE)
    mix: Float[Array, " P"] = eqx.field(converter=as_float, metadata=POSITIVE)

    def __check_init__(self):
        if self.sigmas.ndim != 1 or self.sigmas.shape != self.mix.shape:
            raise ParameterError(
                "MultiScaleBeckmann needs 1-D sigmas and mix of the same length, got shapes "
                f"{self.sigmas.shape} and {self.mix.shape}"
            )
        check_positive("MultiScaleBeckmann", "sigmas", self.sigmas)
        check_positive("MultiScaleBeckmann", "mix", self.mix, allow_zero=True)

    def __call__(self, cos_alpha: Scalar) -> Scalar:
        density = jax.vmap(beckmann, in_axes=(None, 0))(cos_alpha, self.sigmas)
        return density @ (self.mix / jnp.sum(self.mix))
