import math

import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate
from .._convert import FIXED, POSITIVE, as_float, check_positive, check_shape, named
from .._errors import ParameterError
from .._numerics import safe_normalize
from .._typing import Array, Float, Pixel, Scalar
from .._vector import Vec3
from ._light import AbstractFalloff, AbstractLight
from ._point import OFFSET_START_MM, OFFSET_START_RELATIVE, ColocatedLight, irradiance


class LightGuides(AbstractLight):
    """Light guides around the lens: `count` equal point lights on a circle of radius
    `radius_mm` about the optical axis, in the lens plane, the first at `angle` from +x.

    A stereo laparoscope (da Vinci) lights the scene from fibre bundles beside its two
    lenses, a monocular one often from a ring or a crescent of fibres around its lens: one
    point light at the lens, or one offset from it, is then a summary. Two guides put two
    highlights where one light puts one; a ring spreads each highlight. Each guide carries
    `intensity / count` and the falloffs (`InverseSquare`, `SpotFalloff`) of its own
    distance and direction.

    **Arguments:**

    - `radius_mm`: the circle's radius (the capture's length unit), > 0.
    - `angle`: the first guide's angle from +x about the optical axis, radians.
    - `count`: how many guides (2: beside the lens; 6 or more: a ring). Not fitted.
    - `intensity`, `falloff`: as `PointLight`'s.
    """

    radius_mm: Float[Array, ""] = eqx.field(
        converter=as_float, metadata=named("guide_radius_mm", POSITIVE)
    )
    angle: Float[Array, ""] = eqx.field(converter=as_float, metadata=named("guide_angle"))
    count: int = eqx.field(static=True, default=2)
    intensity: Float[Array, ""] = eqx.field(
        converter=as_float, default=1.0, metadata=named("intensity", FIXED)
    )
    falloff: tuple[AbstractFalloff, ...] = ()

    def __check_init__(self):
        check_shape("LightGuides", "radius_mm", self.radius_mm, ())
        check_positive("LightGuides", "radius_mm", self.radius_mm)
        check_shape("LightGuides", "angle", self.angle, ())
        if int(self.count) < 1:
            raise ParameterError(f"LightGuides.count must be at least 1, got {self.count}")

    def positions(self) -> list[Vec3]:
        """Each guide's position in the camera frame."""
        zero = jnp.zeros_like(self.radius_mm)
        return [
            Vec3(
                self.radius_mm * jnp.cos(self.angle + 2 * math.pi * k / self.count),
                self.radius_mm * jnp.sin(self.angle + 2 * math.pi * k / self.count),
                zero,
            )
            for k in range(self.count)
        ]

    def sources(self, point: Vec3, view: Vec3, pixel: Pixel) -> tuple[tuple[Vec3, Scalar], ...]:
        share = self.intensity / self.count
        out = []
        for position in self.positions():
            light_to_point = point - position
            out.append(
                (safe_normalize(-light_to_point), irradiance(share, self.falloff, light_to_point))
            )
        return tuple(out)

    def illuminate(self, point: Vec3, view: Vec3, pixel: Pixel) -> tuple[Vec3, Scalar]:
        """The guides' summary: the irradiance-weighted mean direction and the total."""
        sources = self.sources(point, view, pixel)
        total = sum(irradiance for _, irradiance in sources)
        direction = sum((d * irradiance for d, irradiance in sources), Vec3(0.0, 0.0, 0.0))
        return safe_normalize(direction), total


class LightGuidesCandidate(AbstractCandidate):
    """Light guides around the lens: two beside it (along x, along y) and a ring of 8, from
    a radius of 3 mm (or its share of the working distance without a known size)."""

    name = "light_guides"

    def __call__(self, model, context):
        light = model.light
        if not isinstance(light, ColocatedLight):
            return []
        radius = (
            OFFSET_START_MM
            if context.get("length_unit", "mm") == "mm"
            else OFFSET_START_RELATIVE * context["median_depth_mm"]
        )
        starts = [(2, 0.0), (2, math.pi / 2), (8, 0.0)]
        return [
            eqx.tree_at(
                lambda m: m.light,
                model,
                LightGuides(radius, angle, count, light.intensity, light.falloff),
            )
            for count, angle in starts
        ]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--light-guides",
            type=float,
            nargs=2,
            metavar=("RADIUS_MM", "COUNT"),
            help="COUNT light guides on a circle of RADIUS_MM about the lens (2: beside it)",
        )

    def synth_value(self, args):
        return None if args.light_guides is None else tuple(args.light_guides)

    def synthesize(self, model, value, context):
        radius, count = value
        if int(count) != count or count < 1:
            raise ParameterError(f"--light-guides COUNT must be a positive integer, got {count}")
        light = model.light
        guides = LightGuides(radius, 0.0, int(count), light.intensity, light.falloff)
        return eqx.tree_at(lambda m: m.light, model, guides)
