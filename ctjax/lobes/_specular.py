import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_lobe
from .._convert import POSITIVE, as_rgb, check_positive, check_shape, named
from .._numerics import COSINE_FLOOR, safe_normalize
from .._typing import Array, Float, Scalar
from .._vector import Vec3
from ._beckmann import Beckmann
from ._distribution import AbstractDistribution
from ._factor import AbstractSpecularFactor
from ._lobe import AbstractLobe


class Specular(AbstractLobe):
    """The paper's specular term, eq. (1): `F_tilde * D / (pi (N.L)(N.V))`, times any factors.

    With `Beckmann(sigma)` and no factors this is exactly the paper's model (constant F, no
    geometric attenuation). Note that the paper's term has no `N.L` cosine in front of it,
    so, read as a BRDF (`radiance / N.L`), it is not reciprocal; the term itself is symmetric
    in light and view.

    **Arguments:**

    - `weight`: F_tilde per colour channel (light intensity times Fresnel coefficient), >= 0.
    - `distribution`: the microfacet distribution D (`Beckmann`, `GGX`, `MultiScaleBeckmann`).
    - `factors`: multiplicative factors (`SchlickFresnel`, `GeometricAttenuation`, ...).
    """

    weight: Float[Array, "3"] = eqx.field(converter=as_rgb, metadata=named("F_tilde", POSITIVE))
    distribution: AbstractDistribution
    factors: tuple[AbstractSpecularFactor, ...] = ()
    reciprocal: ClassVar[bool] = False

    def __check_init__(self):
        check_shape("Specular", "weight", self.weight, (3,))
        check_positive("Specular", "weight", self.weight, allow_zero=True)

    def radiance(self, normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
        return microfacet_term(self.distribution, self.factors, normal, light, view)

    def geometry(self, normal: Vec3, light: Vec3, view: Vec3):
        return microfacet_geometry(self.factors, normal, light, view)

    def radiance_given(self, geometry) -> Scalar:
        return microfacet_given(self.distribution, self.factors, geometry)


def _directions(normal: Vec3, light: Vec3, view: Vec3):
    """Whether N.L > 0 and N.V > 0, the half vector, N.H and pi (N.L)(N.V), floored."""
    n_dot_l = normal @ light
    n_dot_v = normal @ view
    lit = (n_dot_l > 0) & (n_dot_v > 0)
    # A light co-located with the camera passes `view` itself: then H = V exactly.
    half = view if light is view else safe_normalize(light + view)
    # N.H > 0 wherever N.L > 0 and N.V > 0; the floors only matter at exact grazing.
    cos_alpha = jnp.clip(normal @ half, COSINE_FLOOR, 1)
    # The floors keep 1 / ((N.L)(N.V)) finite at grazing angles, where D -> 0 anyway.
    denominator = math.pi * jnp.maximum(n_dot_l, COSINE_FLOOR) * jnp.maximum(n_dot_v, COSINE_FLOOR)
    return lit, half, cos_alpha, denominator


def microfacet_term(distribution, factors, normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
    """`D * prod(factors) / (pi (N.L)(N.V))`, 0 unless N.L > 0 and N.V > 0."""
    # (The renderer's hot loop: one division and one select per sample. Written as
    # `microfacet_given(microfacet_geometry(...))` it ran 1.3-1.5x slower at 1080p.)
    lit, half, cos_alpha, denominator = _directions(normal, light, view)
    term = distribution(cos_alpha) / denominator
    for factor in factors:
        term = term * factor(normal, light, view, half)
    return jnp.where(lit, term, 0)


def microfacet_geometry(factors, normal: Vec3, light: Vec3, view: Vec3):
    """What the microfacet term takes of the directions whatever its parameters: N.H, the
    scale 1 / (pi (N.L)(N.V)) (0 unless N.L > 0 and N.V > 0) and, for `factors`, the
    directions and the half vector."""
    lit, half, cos_alpha, denominator = _directions(normal, light, view)
    scale = jnp.where(lit, 1 / denominator, 0)
    return (cos_alpha, scale, (normal, light, view, half)) if factors else (cos_alpha, scale)


def microfacet_given(distribution, factors, geometry) -> Scalar:
    """`microfacet_term` from `microfacet_geometry`."""
    cos_alpha, scale, *directions = geometry
    term = distribution(cos_alpha) * scale
    for factor in factors:
        term = term * factor(*directions[0])
    # Factors are only defined where N.L > 0 and N.V > 0.
    return jnp.where(scale > 0, term, 0) if factors else term


class SecondLobeCandidate(AbstractCandidate):
    """A second specular scale (the paper's eq. 3), sharper or broader than the first."""

    name = "second_lobe"

    def __call__(self, model, context):
        specular = [lobe for lobe in model.brdf.lobes if isinstance(lobe, Specular)]
        if not specular:
            return []
        first = specular[0]
        sigma = getattr(first.distribution, "sigma", jnp.asarray(0.2))
        return [
            with_lobe(
                model,
                Specular(
                    0.3 * first.weight, Beckmann(jnp.clip(sigma * scale, 0.02, 0.9)), first.factors
                ),
            )
            for scale in (0.4, 2.5)
        ]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--second-lobe",
            type=float,
            nargs=2,
            metavar=("SIGMA", "FRACTION"),
            help="a second Beckmann lobe with F_tilde * FRACTION",
        )

    def synth_value(self, args):
        return tuple(args.second_lobe) if args.second_lobe else None

    def synthesize(self, model, value, context):
        sigma, fraction = value
        first = next(lobe for lobe in model.brdf.lobes if isinstance(lobe, Specular))
        lobe = Specular(first.weight * fraction, Beckmann(sigma), first.factors)
        return with_lobe(model, lobe)
