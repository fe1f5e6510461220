import equinox as eqx

from .._candidate import AbstractCandidate, with_effect
from .._convert import POSITIVE, as_rgb, check_positive, check_shape
from .._errors import CtjaxError
from .._typing import RGB, Array, Float
from ._effect import AbstractImageEffect


class Ambient(AbstractImageEffect):
    """A constant ambient (inter-reflected) radiance added to every pixel.

    **Arguments:**

    - `level`: per colour channel, >= 0, linear units (1.0 = 8-bit level 255).
    """

    level: Float[Array, "3"] = eqx.field(converter=as_rgb, metadata=POSITIVE)

    def __check_init__(self):
        check_shape("Ambient", "level", self.level, (3,))
        check_positive("Ambient", "level", self.level, allow_zero=True)

    def __call__(self, rgb: RGB) -> RGB:
        return rgb + self.level

    def inverse(self, rgb: RGB) -> RGB:
        return rgb - self.level


class AmbientCandidate(AbstractCandidate):
    """Ambient radiance (inter-reflections, stray light), added before the camera response."""

    name = "ambient"

    def __call__(self, model, context):
        return [with_effect(model, Ambient(0.01), first=True)]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--ambient",
            type=float,
            nargs="+",
            metavar="A",
            help="ambient radiance, one value or R G B",
        )

    def synth_value(self, args):
        if args.ambient is None:
            return None
        if len(args.ambient) not in (1, 3):
            raise CtjaxError(f"--ambient: expected 1 or 3 values (R G B), got {len(args.ambient)}")
        return tuple(args.ambient) * (3 // len(args.ambient))

    def synthesize(self, model, value, context):
        return with_effect(model, Ambient(value), first=True)
