import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._candidate import AbstractCandidate, with_effect
from .._convert import UNIT_INTERVAL, as_float, as_rgb, check_finite, check_shape, concrete, named
from .._errors import ParameterError
from .._typing import RGB, Array, Float
from ._effect import AbstractImageEffect
from ._srgb import SRGBResponse


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
    - `compressed`: the channels it compresses (default all three); the others' slope is 1
      whatever `slope` says (a fitter sees no derivative in it: give 1 there, the end of
      its domain, which flags nothing). `knee_of` starts one from what `load_capture`
      found on the frames (`Capture.knees`).
    """

    knee: Float[Array, ""] = eqx.field(converter=as_float, metadata=named("knee", UNIT_INTERVAL))
    slope: Float[Array, "3"] = eqx.field(
        converter=as_rgb, metadata=named("knee_slope", UNIT_INTERVAL)
    )
    compressed: tuple[bool, bool, bool] = eqx.field(static=True, default=(True, True, True))

    def __check_init__(self):
        check_shape("Knee", "knee", self.knee, ())
        check_shape("Knee", "slope", self.slope, (3,))
        check_finite("Knee", "knee", self.knee)
        check_finite("Knee", "slope", self.slope)
        if len(self.compressed) != 3 or not any(self.compressed):
            raise ParameterError(
                f"Knee.compressed must name the channels it compresses (3 booleans, one at least "
                f"true), got {self.compressed}"
            )
        for name in ("knee", "slope"):
            value = concrete(getattr(self, name))
            if value is not None and (np.any(value <= 0) or np.any(value > 1)):
                raise ParameterError(f"Knee.{name} must be in (0, 1], got {value}")

    def _slope(self):
        if all(self.compressed):
            return self.slope
        return jnp.where(jnp.asarray(self.compressed), self.slope, 1.0)

    def __call__(self, rgb: RGB) -> RGB:
        return rgb - (1 - self._slope()) * jnp.maximum(rgb - self.knee, 0)

    def inverse(self, rgb: RGB) -> RGB:
        return rgb + (1 / self._slope() - 1) * jnp.maximum(rgb - self.knee, 0)


def knee_of(capture) -> Knee | None:
    """The knee `load_capture` found on `capture`'s frames (`Capture.knees`: the channels
    that rise markedly slower against the others above a bright knot) as a start for a fit,
    or None: `KneeCandidate`'s start (0.5, slope 0.5) in those channels only, the others not
    compressed (`compressed`). Fitted with all three channels free, the second sinus video's
    14 even frames put green's and blue's slopes at 0.03-0.04 beside the spot's falloff (a
    ceiling the frames do not show) where the 28 frames gave 0.86 and 1. Not at the knot
    the note found: that is where red bends against the others' mean (162 of 255 there,
    0.36 decoded), not where the camera's compression starts (a fit put it at 0.64), and
    from there the odd frames' fit lost the knee (red's slope 1)."""
    knees = tuple(getattr(capture, "knees", ()))
    if not knees:
        return None
    compressed = tuple(any(k.channel == c for k in knees) for c in range(3))
    return Knee(0.5, tuple(0.5 if on else 1.0 for on in compressed), compressed)


# A fitted knee below this share of the level where the frames bend (`Capture.knees`,
# decoded) is no highlight compression.
BELOW_THE_BEND = 0.5


def knee_below_the_bend(model, capture) -> str | None:
    """A warning where `model`'s fitted knee sits far below where the capture's frames bend
    (under `BELOW_THE_BEND` of the lowest knot `Capture.knees` found, decoded as the frames
    are), or None: such a knee compresses most of the tissue's values, not the highlights,
    and stands in for something else (a colour that changes with brightness, a falloff).
    On the second sinus video's bulge (frames 2719-2834, every 5th) the default fit put it
    at 0.109 where red bends at 201 of 255 (0.58 decoded), slope 0.72: both models' errors
    fell 2-4%, the lobe's status `no_lobe` either way."""
    knees = tuple(getattr(capture, "knees", ()))
    fitted = [e for e in getattr(model, "effects", ()) if isinstance(e, Knee)]
    if not knees or not fitted:
        return None
    knot = min(k.level for k in knees) / knees[0].top
    if getattr(capture, "encoding", None) == "srgb":  # decoded as the frames are
        knot = float(SRGBResponse().inverse(jnp.full(3, knot))[0])
    level = float(fitted[0].knee)
    if level >= BELOW_THE_BEND * knot:
        return None
    return (
        f"the fitted knee sits at {level:.3g}, far below where the frames bend ({knot:.3g}, "
        "decoded): it compresses most of the tissue's values, not the highlights, and stands "
        "in for something the model lacks (a colour that changes with brightness, a falloff); "
        "--effects none fits without it"
    )


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
