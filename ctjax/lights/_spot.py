from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_falloff
from .._convert import FIXED, POSITIVE, as_float, check_positive, check_shape
from .._numerics import safe_normalize
from .._typing import Array, Float, Scalar
from .._vector import Vec3
from ._light import AbstractFalloff


class SpotFalloff(AbstractFalloff):
    """Angular falloff of the light guide: `cos^k` of the angle to its axis, 0 behind it.

    **Arguments:**

    - `exponent`: k >= 0 (0: isotropic).
    - `axis`: the light guide's axis in the camera frame (default: the optical axis +z).
    """

    name: ClassVar[str] = "spot"

    exponent: Float[Array, ""] = eqx.field(converter=as_float, metadata=POSITIVE)
    axis: Float[Array, "3"] = eqx.field(converter=as_float, default=(0.0, 0.0, 1.0), metadata=FIXED)

    def __check_init__(self):
        check_shape("SpotFalloff", "exponent", self.exponent, ())
        check_positive("SpotFalloff", "exponent", self.exponent, allow_zero=True)
        check_shape("SpotFalloff", "axis", self.axis, (3,))

    def __call__(self, light_to_point: Vec3) -> Scalar:
        cosine = safe_normalize(light_to_point) @ safe_normalize(Vec3.from_array(self.axis))
        ahead = cosine > 0
        # cos^k as exp(k log cos), guarded so k -> 0 and cos -> 0 keep finite gradients.
        return jnp.where(ahead, jnp.exp(self.exponent * jnp.log(jnp.where(ahead, cosine, 1))), 0)


class SpotFalloffCandidate(AbstractCandidate):
    """The light guide's angular falloff, from a broad and a narrow start."""

    name = "spot_falloff"

    def __call__(self, model, context):
        return [with_falloff(model, SpotFalloff(k)) for k in (1.0, 4.0)]

    def add_synth_arguments(self, group):
        group.add_argument("--spot", type=float, metavar="K", help="angular falloff cos^K")

    def synth_value(self, args):
        return args.spot

    def synthesize(self, model, value, context):
        return with_falloff(model, SpotFalloff(value))
