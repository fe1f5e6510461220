import equinox as eqx
import jax.numpy as jnp

from .._convert import UNIT_INTERVAL, as_float, check_positive, check_shape
from .._typing import Array, Float, Scalar
from .._vector import Vec3
from ._factor import AbstractSpecularFactor


class SchlickFresnel(AbstractSpecularFactor):
    """Schlick's Fresnel angle dependence, relative to normal incidence.

    `F(theta) / F0 = 1 + (1/F0 - 1) (1 - V.H)^5`, so the specular weight keeps its meaning
    (`F_tilde` = intensity times the Fresnel coefficient at normal incidence). With the light
    co-located with the camera, V.H = 1 and the factor is exactly 1: only an offset light
    reveals it.

    **Arguments:**

    - `f0`: Fresnel reflectance at normal incidence, in (0, 1] (water/tissue: about 0.02).
    """

    f0: Float[Array, ""] = eqx.field(converter=as_float, metadata=UNIT_INTERVAL)

    def __check_init__(self):
        check_shape("SchlickFresnel", "f0", self.f0, ())
        check_positive("SchlickFresnel", "f0", self.f0)

    def __call__(self, normal: Vec3, light: Vec3, view: Vec3, half: Vec3) -> Scalar:
        one_minus = jnp.clip(1 - view @ half, 0, 1)
        return 1 + (1 / self.f0 - 1) * one_minus**5
