"""Multiplicative factors of the specular term: Fresnel's angle dependence, masking/shadowing.

The paper takes F constant and drops Cook-Torrance's geometric attenuation G; each is a
factor here, so adding one is `Specular(F, Beckmann(s), factors=(SchlickFresnel(0.02),))`.
"""

import abc

import equinox as eqx

from .._typing import Scalar
from .._vector import Vec3


class AbstractSpecularFactor(eqx.Module):
    """A dimensionless factor multiplying the specular term (1 = no effect).

    Called with the unit normal, light, view and half vector (camera frame); only ever
    evaluated where N.L > 0 and N.V > 0. Must be finite and >= 0 there.
    """

    @abc.abstractmethod
    def __call__(self, normal: Vec3, light: Vec3, view: Vec3, half: Vec3) -> Scalar:
        """The factor's value for one set of directions."""
