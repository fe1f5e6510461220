import abc
from typing import NamedTuple

import equinox as eqx

from .._typing import RGB, Array, Float, Int, Pixel


class Site(NamedTuple):
    """Where a pixel value was recorded: its pixel centre (u, v) and the index of its frame
    in the capture. What a camera-side effect may depend on (vignetting: the pixel;
    auto-exposure: the frame)."""

    pixel: Pixel
    frame: Int[Array, ""]


class AbstractImageEffect(eqx.Module):
    """A per-pixel effect between scene radiance and the recorded pixel value.

    Effects apply in the order given to the renderer, after the lobes are summed (e.g. an
    ambient term, then the camera response). An effect that depends on where the value was
    recorded (the pixel, the frame) says so in `at`: every caller applies `effect.at(site)`,
    so `__call__` and `inverse` stay functions of the RGB alone.
    """

    @abc.abstractmethod
    def __call__(self, rgb: RGB) -> RGB:
        """The pixel's RGB after the effect (linear units, 1.0 = 8-bit level 255)."""

    def inverse(self, rgb: RGB) -> RGB:
        """The radiance before the effect, where it can be undone (fitters use it to start
        the linear weights in closed form). Not invertible by default: returns `rgb`."""
        return rgb

    def at(self, site: Site) -> "AbstractImageEffect":
        """The effect at one pixel of one frame (default: the same everywhere)."""
        return self


class Gain(AbstractImageEffect):
    """The radiance times a factor: what an exposure or a vignetting is at one pixel.

    **Arguments:**

    - `factor`: > 0 (1: no effect).
    """

    factor: Float[Array, ""]

    def __call__(self, rgb: RGB) -> RGB:
        return rgb * self.factor

    def inverse(self, rgb: RGB) -> RGB:
        return rgb / self.factor


def apply_effects(effects, rgb: RGB, site: Site) -> RGB:
    """`effects` applied in order to one recorded value's RGB."""
    for effect in effects:
        rgb = effect.at(site)(rgb)
    return rgb


def undo_effects(effects, rgb: RGB, site: Site) -> RGB:
    """`effects` undone (their `inverse`), last first: the radiance where it can be."""
    for effect in reversed(tuple(effects)):
        rgb = effect.at(site).inverse(rgb)
    return rgb
