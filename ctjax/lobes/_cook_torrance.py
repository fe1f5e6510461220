import equinox as eqx

from .._convert import POSITIVE, as_rgb, check_positive, check_shape, named
from .._typing import Array, Float, Scalar
from .._vector import Vec3
from ._distribution import AbstractDistribution
from ._factor import AbstractSpecularFactor
from ._lobe import AbstractLobe
from ._specular import microfacet_geometry, microfacet_given, microfacet_term


class CookTorrance(AbstractLobe):
    """Cook & Torrance's (1982) specular BRDF, `f = F D G / (pi (N.L)(N.V))`, as a lobe.

    The same term as the paper's `Specular` read as a BRDF: its radiance carries the
    `N.L` cosine, so it is reciprocal. Use it for measured BRDF data (ALTA files); the
    paper's image model is `Specular`. D uses the paper's normalisation (as Cook and
    Torrance did); G and a Fresnel angle dependence are `factors`.

    **Arguments:**

    - `weight`: F (times the light intensity, for images) per colour channel, >= 0.
    - `distribution`: `Beckmann`, `GGX`, `MultiScaleBeckmann`.
    - `factors`: `SchlickFresnel`, `GeometricAttenuation`, ...
    """

    weight: Float[Array, "3"] = eqx.field(converter=as_rgb, metadata=named("F_tilde", POSITIVE))
    distribution: AbstractDistribution
    factors: tuple[AbstractSpecularFactor, ...] = ()

    def __check_init__(self):
        check_shape("CookTorrance", "weight", self.weight, (3,))
        check_positive("CookTorrance", "weight", self.weight, allow_zero=True)

    def radiance(self, normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
        term = microfacet_term(self.distribution, self.factors, normal, light, view)
        return term * (normal @ light)

    def geometry(self, normal: Vec3, light: Vec3, view: Vec3):
        cos_alpha, scale, *directions = microfacet_geometry(self.factors, normal, light, view)
        return cos_alpha, scale * (normal @ light), *directions  # 0 where N.L <= 0

    def radiance_given(self, geometry) -> Scalar:
        return microfacet_given(self.distribution, self.factors, geometry)
