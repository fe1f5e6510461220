"""A point light in the lens plane: the scope's light outlets on the face of its tip."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate
from .._convert import FIXED, as_float, check_finite, check_positive, check_shape, named
from .._numerics import safe_normalize
from .._typing import Array, Float, Pixel, Scalar
from .._vector import Vec3
from ._light import AbstractFalloff, AbstractLight
from ._point import ColocatedLight, PointLight, irradiance, offset_starts


class LensPlaneLight(AbstractLight):
    """A point light at `offset_mm` = (x, y) in the lens plane (z = 0 in the camera frame).

    A laparoscope's or an endoscope's light leaves the fibres that end on the face of its
    tip, beside the lens or around it (a da Vinci's two guides, a sinus scope's ring); the
    face is the lens plane, square to the optical axis (an angled scope's too: its lens and
    fibres share the slanted face). So the light's offset along the axis is 0 by the scope's
    construction, and it is also what the images determine worst: moving the light along
    the axis changes every point's distance to it almost alike, which each point's albedo
    absorbs, and the rest of its signature is of the size of a reconstruction's normal
    errors (on `ctjax synth --stereo 5 --light-offset 4 -3 0 --inverse-square`, 320x256 x 5,
    reconstructed: a `PointLight` fitted 0.80 mm off, 0.76 of it along the axis).
    `PointLight` fits the axis too.

    **Arguments:**

    - `offset_mm`: the light's (x right, y down) position in the lens plane, mm.
    - `intensity`: irradiance factor (with `InverseSquare`, at its reference distance).
    - `falloff`: irradiance factors of position (`InverseSquare`, `SpotFalloff`).
    """

    # The dotted name of the fitted position (`hold` and `freeze` take it).
    position_field: ClassVar[str] = "offset_mm"

    offset_mm: Float[Array, "2"] = eqx.field(
        converter=as_float, metadata=named("lens_plane_offset_mm")
    )
    intensity: Float[Array, ""] = eqx.field(
        converter=as_float, default=1.0, metadata=named("intensity", FIXED)
    )
    falloff: tuple[AbstractFalloff, ...] = ()

    def __check_init__(self):
        check_shape("LensPlaneLight", "offset_mm", self.offset_mm, (2,))
        check_finite("LensPlaneLight", "offset_mm", self.offset_mm)
        check_shape("LensPlaneLight", "intensity", self.intensity, ())
        check_positive("LensPlaneLight", "intensity", self.intensity, allow_zero=True)

    @property
    def position_mm(self) -> Float[Array, "3"]:
        """The light's position in the camera frame, (x, y, 0)."""
        return jnp.concatenate([self.offset_mm, jnp.zeros((1,), self.offset_mm.dtype)])

    def illuminate(self, point: Vec3, view: Vec3, pixel: Pixel) -> tuple[Vec3, Scalar]:
        light_to_point = point - Vec3.from_array(self.position_mm)
        direction = safe_normalize(-light_to_point)
        return direction, irradiance(self.intensity, self.falloff, light_to_point)


class LightOffsetCandidate(AbstractCandidate):
    """The light guide beside the lens: a point light at an offset in the lens plane
    (`LensPlaneLight`, where a scope's fibres end; `calibrate-light`'s default too), from
    four starts (the cost is not convex in the position). Free along the optical axis, a
    point light stood in for a falloff the model lacks: on the shared sinus video it went
    1.08 working distances behind the lens. (`synthesize` places it anywhere.)"""

    name = "light_offset"

    def __call__(self, model, context):
        light = model.light
        if not isinstance(light, ColocatedLight):
            return []
        offsets = offset_starts(context.get("length_unit", "mm"), context["median_depth_mm"])
        return [
            eqx.tree_at(
                lambda m: m.light,
                model,
                LensPlaneLight(jnp.asarray(o[:2], float), falloff=light.falloff),
            )
            for o in offsets
        ]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--light-offset",
            type=float,
            nargs=3,
            metavar=("X", "Y", "Z"),
            help="point light at this camera-frame offset from the lens, mm",
        )

    def synth_value(self, args):
        return tuple(args.light_offset) if args.light_offset else None

    def synthesize(self, model, value, context):
        light = PointLight(jnp.asarray(value, float), falloff=model.light.falloff)
        return eqx.tree_at(lambda m: m.light, model, light)
