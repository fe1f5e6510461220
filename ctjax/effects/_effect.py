import abc

import equinox as eqx

from .._typing import RGB


class AbstractImageEffect(eqx.Module):
    """A per-pixel effect between scene radiance and the recorded pixel value.

    Effects apply in the order given to the renderer, after the lobes are summed (e.g. an
    ambient term, then the camera response).
    """

    @abc.abstractmethod
    def __call__(self, rgb: RGB) -> RGB:
        """The pixel's RGB after the effect (linear units, 1.0 = 8-bit level 255)."""

    def inverse(self, rgb: RGB) -> RGB:
        """The radiance before the effect, where it can be undone (fitters use it to start
        the linear weights in closed form). Not invertible by default: returns `rgb`."""
        return rgb
