from typing import ClassVar

import equinox as eqx

from .._convert import FIXED, as_float, check_finite, check_positive, check_shape, named
from .._numerics import safe_normalize
from .._typing import Array, Float, Pixel, Scalar
from .._vector import Vec3
from ._light import AbstractFalloff, AbstractLight


def irradiance(intensity: Scalar, falloff: tuple, light_to_point: Vec3) -> Scalar:
    factor = intensity
    for effect in falloff:
        factor = factor * effect(light_to_point)
    return factor


class ColocatedLight(AbstractLight):
    """The paper's light: a point light at the camera centre, so `L = V` at every pixel.

    **Arguments:**

    - `intensity`: irradiance factor (the paper absorbs it into rho_tilde and F_tilde: 1).
    - `falloff`: irradiance factors of position (`InverseSquare`, `SpotFalloff`); the paper
      uses none.
    """

    intensity: Float[Array, ""] = eqx.field(
        converter=as_float, default=1.0, metadata=named("intensity", FIXED)
    )
    falloff: tuple[AbstractFalloff, ...] = ()

    def __check_init__(self):
        check_shape("ColocatedLight", "intensity", self.intensity, ())
        check_positive("ColocatedLight", "intensity", self.intensity, allow_zero=True)

    def illuminate(self, point: Vec3, view: Vec3, pixel: Pixel) -> tuple[Vec3, Scalar]:
        # `view` itself, not a recomputed copy: lobes then know L = V exactly (`light is
        # view`), and the specular half vector is V without another normalisation.
        return view, irradiance(self.intensity, self.falloff, point)


class PointLight(AbstractLight):
    """A point light at `position_mm` in the camera frame: the light guide offset from the lens.

    **Arguments:**

    - `position_mm`: the light's position (x right, y down, z forward), mm.
    - `intensity`: irradiance factor (with `InverseSquare`, at its reference distance).
    - `falloff`: irradiance factors of position (`InverseSquare`, `SpotFalloff`).
    """

    # The dotted name of the fitted position (`hold` and `freeze` take it).
    position_field: ClassVar[str] = "position_mm"

    position_mm: Float[Array, "3"] = eqx.field(converter=as_float, metadata=named("offset_mm"))
    intensity: Float[Array, ""] = eqx.field(
        converter=as_float, default=1.0, metadata=named("intensity", FIXED)
    )
    falloff: tuple[AbstractFalloff, ...] = ()

    def __check_init__(self):
        check_shape("PointLight", "position_mm", self.position_mm, (3,))
        check_finite("PointLight", "position_mm", self.position_mm)
        check_shape("PointLight", "intensity", self.intensity, ())
        check_positive("PointLight", "intensity", self.intensity, allow_zero=True)

    def illuminate(self, point: Vec3, view: Vec3, pixel: Pixel) -> tuple[Vec3, Scalar]:
        light_to_point = point - Vec3.from_array(self.position_mm)
        direction = safe_normalize(-light_to_point)
        return direction, irradiance(self.intensity, self.falloff, light_to_point)


# The light guide sits a few mm off the lens: offset fits start this far along +-x, +-y ...
OFFSET_START_MM = 3.0
# ... which, in a capture without a known size (lengths in median depths), is this fraction
# of the median depth (3 mm at a laparoscope's typical 60 mm).
OFFSET_START_RELATIVE = OFFSET_START_MM / 60.0


def offset_starts(length_unit: str = "mm", median_depth: float = 1.0) -> list[tuple]:
    """The starting offsets of a light-offset fit (the cost is not convex in the position),
    in the capture's length unit."""
    step = OFFSET_START_MM if length_unit == "mm" else OFFSET_START_RELATIVE * median_depth
    return [(step, 0.0, 0.0), (-step, 0.0, 0.0), (0.0, step, 0.0), (0.0, -step, 0.0)]


def default_light(light: AbstractLight | None) -> AbstractLight:
    """`light`, or the paper's (`ColocatedLight()`: L = V) where it is None, made at the
    call: a default made at import would hold its intensity in the precision in force then
    (`jax_enable_x64`), and a kept program's key with it."""
    return ColocatedLight() if light is None else light
