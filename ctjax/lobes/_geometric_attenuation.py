import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_factor
from .._typing import Scalar
from .._vector import Vec3
from ._factor import AbstractSpecularFactor


class GeometricAttenuation(AbstractSpecularFactor):
    """Cook-Torrance's masking/shadowing term G (Cook & Torrance 1982, after Torrance-Sparrow).

    `G = min(1, 2 (N.H)(N.V) / (V.H), 2 (N.H)(N.L) / (V.H))`. The paper omits it; it darkens
    the specular term at grazing angles (with a co-located light, G = min(1, 2 (N.V)^2)).
    """

    def __call__(self, normal: Vec3, light: Vec3, view: Vec3, half: Vec3) -> Scalar:
        n_dot_h = normal @ half
        # V.H > 0 because H bisects L and V; the floor guards only L = -V exactly.
        v_dot_h = jnp.maximum(view @ half, 1e-12)
        masking = 2 * n_dot_h * (normal @ view) / v_dot_h
        shadowing = 2 * n_dot_h * (normal @ light) / v_dot_h
        return jnp.clip(jnp.minimum(masking, shadowing), 0, 1)


class GeometricAttenuationCandidate(AbstractCandidate):
    """Cook-Torrance's masking and shadowing G on every microfacet lobe."""

    name = "geometric_attenuation"

    def __call__(self, model, context):
        return [with_factor(model, GeometricAttenuation())]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--geometric-attenuation",
            action="store_true",
            help="Cook-Torrance geometric attenuation G",
        )

    def synth_value(self, args):
        return True if args.geometric_attenuation else None

    def synthesize(self, model, value, context):
        return with_factor(model, GeometricAttenuation())
