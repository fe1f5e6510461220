import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._candidate import AbstractCandidate, with_effect
from .._convert import UNIT_INTERVAL, as_float, as_rgb, check_finite, check_shape, concrete, named
from .._errors import ParameterError
from .._typing import RGB, Array, Float
from ._effect import AbstractImageEffect


class Knee(AbstractImageEffect):
    """A video camera's knee: above the `knee` level each channel's value rises `slope`
    times as fast as the radiance, `pixel = x - (1 - slope) max(x - knee, 0)`.

    Broadcast and endoscope cameras compress their highlights this way, so that a specular
    highlight keeps some detail before the 8-bit ceiling: a Cook-Torrance lobe fitted
    without it predicts highlights brighter than recorded, and the fit widens or drops the
    lobe to match them. Per channel because the processing chain (white balance before the
    knee) compresses a channel that sits higher sooner. In the units the fit sees (linear,
    after the capture's declared encoding is decoded), applied last: after the exposure,
    the vignetting and an ambient radiance, as in the camera.

    **Arguments:**

    - `knee`: where the compression starts, in (0, 1) (1.0 = 8-bit level 255).
    - `slope`: per colour channel, in (0, 1] (1: no compression).
    """

    knee: Float[Array, ""] = eqx.field(converter=as_float, metadata=named("knee", UNIT_INTERVAL))
    slope: Float[Array, "3"] = eqx.field(
        converter=as_rgb, metadata=named("knee_slope", UNIT_INTERVAL)
    )

    def __check_init__(self):
        check_shape("Knee", "knee", self.knee, ())
        check_shape("Knee", "slope", self.slope, (3,))
        check_finite("Knee", "knee", self.knee)
        check_finite("Knee", "slope", self.slope)
        for name in ("knee", "slope"):
            value = concrete(getattr(self, name))
            if value is not None and (np.any(value <= 0) or np.any(value > 1)):
                raise ParameterError(f"Knee.{name} must be in (0, 1], got {value}")

    def __call__(self, rgb: RGB) -> RGB:
        return rgb - (1 - self.slope) * jnp.maximum(rgb - self.knee, 0)

    def inverse(self, rgb: RGB) -> RGB:
        return rgb + (1 / self.slope - 1) * jnp.maximum(rgb - self.knee, 0)


class KneeCandidate(AbstractCandidate):
    """The camera's highlight compression: from a knee at 0.5 (sRGB-encoded level 188),
    each channel's slope from 0.5."""

    name = "knee"

    def __call__(self, model, context):
        if any(isinstance(effect, Knee) for effect in model.effects):
            return []
        return [with_effect(model, Knee(0.5, 0.5))]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--knee",
            type=float,
            nargs="+",
            metavar="V",
            help="highlight compression: KNEE SLOPE or KNEE SLOPE_R SLOPE_G SLOPE_B (linear)",
        )

    def synth_value(self, args):
        if args.knee is None:
            return None
        if len(args.knee) not in (2, 4):
            raise ParameterError(
                f"--knee: expected KNEE SLOPE or KNEE SLOPE_R SLOPE_G SLOPE_B, got {args.knee}"
            )
        return args.knee[0], tuple(args.knee[1:]) * (3 // (len(args.knee) - 1))

    def synthesize(self, model, value, context):
        knee, slope = value
        return with_effect(model, Knee(knee, slope))
