from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_falloff
from .._convert import FIXED, as_float, check_positive, check_shape
from .._typing import Array, Float, Scalar
from .._vector import Vec3
from ._light import AbstractFalloff


class InverseSquare(AbstractFalloff):
    """Inverse-square falloff of a point light, normalised at a reference distance.

    `(reference_mm / d)^2`, so the light's intensity is its irradiance at `reference_mm`.
    Finite at the light's position (d is floored at 1 micrometre).

    **Arguments:**

    - `reference_mm`: distance at which the factor is 1, mm (> 0).
    """

    name: ClassVar[str] = "inverse_square"

    reference_mm: Float[Array, ""] = eqx.field(converter=as_float, default=50.0, metadata=FIXED)

    def __check_init__(self):
        check_shape("InverseSquare", "reference_mm", self.reference_mm, ())
        check_positive("InverseSquare", "reference_mm", self.reference_mm)

    def __call__(self, light_to_point: Vec3) -> Scalar:
        distance2 = jnp.maximum(light_to_point @ light_to_point, 1e-6)
        return self.reference_mm**2 / distance2


class InverseSquareCandidate(AbstractCandidate):
    """Irradiance falling with the square of the distance, referenced at the working
    distance (so that the weights keep their meaning there)."""

    name = "inverse_square"

    def __call__(self, model, context):
        return [with_falloff(model, InverseSquare(context["median_depth_mm"]))]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--inverse-square",
            action="store_true",
            help="inverse-square falloff (1 at the working distance, 70 mm)",
        )

    def synth_value(self, args):
        return True if args.inverse_square else None

    def synthesize(self, model, value, context):
        return with_falloff(model, InverseSquare(context["working_distance_mm"]))
