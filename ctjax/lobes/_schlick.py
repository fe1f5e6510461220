import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_factor
from .._convert import UNIT_INTERVAL, as_float, check_positive, check_shape, concrete
from .._errors import ParameterError
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
    - `cosine`: the angle Fresnel is taken at: "half" (V.H, the microfacet's incidence:
      Cook-Torrance) or "normal" (N.V, a common shortcut in renderers, which darkens the
      specular term away from grazing even with a co-located light).
    """

    f0: Float[Array, ""] = eqx.field(converter=as_float, metadata=UNIT_INTERVAL)
    cosine: str = eqx.field(static=True, default="half")

    def __check_init__(self):
        check_shape("SchlickFresnel", "f0", self.f0, ())
        check_positive("SchlickFresnel", "f0", self.f0)
        value = concrete(self.f0)
        if value is not None and value > 1:
            raise ParameterError(f"SchlickFresnel.f0 must be in (0, 1], got {float(value)}")
        if self.cosine not in ("half", "normal"):
            raise ParameterError(
                f"SchlickFresnel.cosine must be 'half' or 'normal', got {self.cosine!r}"
            )

    def __call__(self, normal: Vec3, light: Vec3, view: Vec3, half: Vec3) -> Scalar:
        cosine = view @ half if self.cosine == "half" else normal @ view
        one_minus = jnp.clip(1 - cosine, 0, 1)
        return 1 + (1 / self.f0 - 1) * one_minus**5


class FresnelSchlickCandidate(AbstractCandidate):
    """Schlick's Fresnel factor on every microfacet lobe."""

    name = "fresnel_schlick"

    def __call__(self, model, context):
        # Cook-Torrance's V.H, and the N.V shortcut that many renderers use.
        return [with_factor(model, SchlickFresnel(0.05, cosine)) for cosine in ("half", "normal")]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--fresnel-schlick", type=float, metavar="F0", help="Schlick Fresnel with this F0"
        )
        group.add_argument(
            "--fresnel-cosine",
            choices=("half", "normal"),
            default="half",
            help="Schlick at V.H (Cook-Torrance, default) or at N.V",
        )

    def synth_value(self, args):
        if args.fresnel_schlick is None:
            return None
        return (args.fresnel_schlick, args.fresnel_cosine)

    def synthesize(self, model, value, context):
        f0, cosine = value if isinstance(value, tuple | list) else (value, "half")
        return with_factor(model, SchlickFresnel(f0, cosine))
