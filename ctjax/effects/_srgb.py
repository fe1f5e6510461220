import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_effect
from .._typing import RGB
from ._effect import AbstractImageEffect

# IEC 61966-2-1: the linear toe below this linear value, the power above it.
_TOE = 0.0031308


class SRGBResponse(AbstractImageEffect):
    """The sRGB encoding curve as the camera's response: `pixel = 12.92 radiance` on the
    toe, `1.055 radiance^(1/2.4) - 0.055` above it (radiance clipped at 0).

    What every video and JPEG frame went through before it was recorded; ctjax decodes it
    on load (`camera.json`'s `"encoding"`). This effect is the diagnosis of a capture
    declared `"linear"` whose images are encoded: unlike a power law, its toe and offset
    are not absorbed by per-point albedos.
    """

    def __call__(self, rgb: RGB) -> RGB:
        x = jnp.maximum(rgb, 0)
        above = x > _TOE
        power = 1.055 * jnp.exp(jnp.log(jnp.where(above, x, 1)) / 2.4) - 0.055
        return jnp.where(above, power, 12.92 * x)

    def inverse(self, rgb: RGB) -> RGB:
        e = jnp.maximum(rgb, 0)
        above = e > 0.04045
        power = jnp.exp(2.4 * jnp.log(jnp.where(above, (e + 0.055) / 1.055, 1)))
        return jnp.where(above, power, e / 12.92)


class SRGBResponseCandidate(AbstractCandidate):
    """The camera's sRGB response, on a capture read as linear (a wrong `"encoding"`)."""

    name = "srgb_response"

    def __call__(self, model, context):
        if any(isinstance(effect, SRGBResponse) for effect in model.effects):
            return []
        return [with_effect(model, SRGBResponse())]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--srgb-response",
            action="store_true",
            help="record the images sRGB-encoded but declare them linear (a wrong encoding)",
        )

    def synth_value(self, args):
        return True if args.srgb_response else None

    def synthesize(self, model, value, context):
        return with_effect(model, SRGBResponse())
