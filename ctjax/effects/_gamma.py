import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_effect
from .._convert import POSITIVE, as_float, check_positive, check_shape
from .._typing import RGB, Array, Float
from ._effect import AbstractImageEffect


class CameraGamma(AbstractImageEffect):
    """A power-law camera response: `pixel = radiance^(1 / gamma)` (radiance clipped at 0).

    **Arguments:**

    - `gamma`: > 0; 1 is linear, about 2.2 for an sRGB-like response.
    """

    gamma: Float[Array, ""] = eqx.field(converter=as_float, metadata=POSITIVE)

    def __check_init__(self):
        check_shape("CameraGamma", "gamma", self.gamma, ())
        check_positive("CameraGamma", "gamma", self.gamma)

    def __call__(self, rgb: RGB) -> RGB:
        # x^(1/g) has an unbounded derivative at 0: below 1e-12 the pixel is black anyway.
        lit = rgb > 1e-12
        return jnp.where(lit, jnp.exp(jnp.log(jnp.where(lit, rgb, 1)) / self.gamma), 0)

    def inverse(self, rgb: RGB) -> RGB:
        return jnp.maximum(rgb, 0) ** self.gamma


class CameraGammaCandidate(AbstractCandidate):
    """A camera response radiance^(1/gamma), from a mild and a standard gamma."""

    name = "camera_gamma"

    def __call__(self, model, context):
        return [with_effect(model, CameraGamma(g)) for g in (1.3, 2.2)]

    def add_synth_arguments(self, group):
        group.add_argument("--gamma", type=float, help="camera response radiance^(1/gamma)")

    def synth_value(self, args):
        return args.gamma

    def synthesize(self, model, value, context):
        return with_effect(model, CameraGamma(value))
