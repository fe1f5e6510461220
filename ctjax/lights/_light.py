import abc
from typing import ClassVar

import equinox as eqx

from .._typing import Pixel, Scalar
from .._vector import Vec3


class AbstractLight(eqx.Module):
    """The laparoscope's light, in the camera frame (x right, y down, z forward, mm)."""

    @abc.abstractmethod
    def illuminate(self, point: Vec3, view: Vec3, pixel: Pixel) -> tuple[Vec3, Scalar]:
        """Unit direction from `point` towards the light, and the irradiance factor there.

        `view` is the unit direction from `point` to the lens the light is mounted on (the
        camera centre; a stereo scope's right camera sees from elsewhere); `pixel` the (u, v)
        pixel the point is seen at (used by per-pixel light fields). The irradiance factor
        multiplies every lobe; 1 for the paper's light. A light of several sources (light
        guides around the lens) gives its single-direction summary here (the estimators
        that take one light direction per pixel use it) and each source in `sources`.
        """

    def sources(self, point: Vec3, view: Vec3, pixel: Pixel) -> tuple[tuple[Vec3, Scalar], ...]:
        """Every source's (direction, irradiance factor) at `point`: the renderer sums the
        lobes over them. One source, `illuminate`'s, by default."""
        return (self.illuminate(point, view, pixel),)


class AbstractFalloff(eqx.Module):
    """A dimensionless irradiance factor of a light at a position (1 = no effect).

    `name` is how the JSON outputs and `ctjax calibrate-light --falloff` call it.
    """

    name: ClassVar[str]

    @abc.abstractmethod
    def __call__(self, light_to_point: Vec3) -> Scalar:
        """Factor for the vector from the light's position to the surface point (mm)."""
