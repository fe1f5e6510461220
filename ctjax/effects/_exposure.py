import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._candidate import AbstractCandidate, with_effect
from .._convert import PER_FRAME, as_float, check_finite, named
from .._errors import CtjaxError, ParameterError
from .._typing import RGB, Array, Float
from ._effect import AbstractImageEffect, Gain, Site


class FrameExposure(AbstractImageEffect):
    """Each frame's exposure relative to the first frame's: the radiance of frame f times
    `exp(log_exposure[f - 1])` before the camera's response (frame 0: times 1).

    What an endoscope's auto-exposure (its shutter, gain or light power) changes from frame
    to frame. Relative to one frame because the albedo absorbs a common factor. Its values
    are each frame's own: the held-out protocol fits a held-out frame's on that frame
    (`PER_FRAME`; `ctjax.heldout`).

    **Arguments:**

    - `log_exposure`: natural log of frames 1 .. F-1's exposure over frame 0's, (F - 1,).
    """

    log_exposure: Float[Array, " frames_minus_one"] = eqx.field(
        converter=as_float, metadata=named("log_exposure", PER_FRAME)
    )

    def __check_init__(self):
        if jnp.ndim(self.log_exposure) != 1:
            raise ParameterError(
                f"FrameExposure.log_exposure must be one value per frame after the first, "
                f"got shape {jnp.shape(self.log_exposure)}"
            )
        check_finite("FrameExposure", "log_exposure", self.log_exposure)

    @property
    def exposure(self) -> Float[Array, " frames"]:
        """Every frame's exposure over the first frame's (F,)."""
        zero = jnp.zeros((1,), self.log_exposure.dtype)
        return jnp.exp(jnp.concatenate([zero, self.log_exposure]))

    def at(self, site: Site) -> Gain:
        return Gain(self.exposure[site.frame])

    def __call__(self, rgb: RGB) -> RGB:
        raise CtjaxError("FrameExposure depends on the frame: apply `effect.at(site)`")


class FrameExposureCandidate(AbstractCandidate):
    """Auto-exposure: one exposure per frame, from none (every frame as the first)."""

    name = "frame_exposure"

    def __call__(self, model, context):
        frames = int(context.get("frames", 0))
        if frames < 2 or any(isinstance(effect, FrameExposure) for effect in model.effects):
            return []
        # Before the camera's response (the sensor's exposure scales the radiance).
        return [with_effect(model, FrameExposure(np.zeros(frames - 1)), first=True)]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--exposure",
            type=float,
            metavar="S",
            help="auto-exposure: each frame's exposure exp(N(0, S^2)) times the first's",
        )

    def synth_value(self, args):
        return args.exposure

    def synthesize(self, model, value, context):
        frames = int(context["frames"])
        if value < 0 or not np.isfinite(value):
            raise ParameterError(f"--exposure must be >= 0, got {value}")
        rng = np.random.default_rng(int(context.get("seed", 0)) + 7919)
        return with_effect(model, FrameExposure(rng.normal(0.0, value, frames - 1)), first=True)
