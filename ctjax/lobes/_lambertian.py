import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate
from .._convert import POSITIVE, as_rgb, check_positive, check_shape, named
from .._typing import Array, Float, Scalar
from .._vector import Vec3
from ._lobe import AbstractLobe


class Lambertian(AbstractLobe):
    """Lambertian diffuse lobe: `rho_tilde / pi * (N.L)` (paper eq. 1, first term).

    **Arguments:**

    - `weight`: rho_tilde per colour channel (light intensity times albedo; linear units
      where 1.0 is 8-bit level 255), >= 0.
    """

    weight: Float[Array, "3"] = eqx.field(converter=as_rgb, metadata=named("rho_tilde", POSITIVE))
    # The name under which a fit offers this diffuse term (`--diffuse`); a subclass with a
    # shape of its own sets its own (`ctjax.lobes._diffuse`).
    diffuse_name: ClassVar[str] = "lambertian"

    def __check_init__(self):
        check_shape("Lambertian", "weight", self.weight, (3,))
        check_positive("Lambertian", "weight", self.weight, allow_zero=True)

    def radiance(self, normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
        return _cosine_over_pi(normal, light, view)

    def geometry(self, normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
        return _cosine_over_pi(normal, light, view)  # no nonlinear parameter: the radiance

    def radiance_given(self, geometry: Scalar) -> Scalar:
        return geometry


def _cosine_over_pi(normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
    # Zero on back-facing surfaces (N.V <= 0) as well, like every lobe; one select, so the
    # gradient is exactly 0 there too.
    n_dot_l = normal @ light
    return jnp.where((n_dot_l > 0) & (normal @ view > 0), n_dot_l, 0) / math.pi


class AlbedoTextureCandidate(AbstractCandidate):
    """A spatially varying albedo: the Lambertian lobe's weight per surface point and
    channel (textured tissue), estimated from every frame that sees the point (the albedo
    map). Offered when the base model has one albedo for the capture (`--albedo
    uniform`): the model is the same, what changes is how it is fitted (`albedo = "map"`)."""

    name = "albedo_texture"
    albedo: ClassVar[str] = "map"

    def __call__(self, model, context):
        # The map follows surface points across frames: it needs depth and poses.
        if context.get("albedo") != "uniform" or not context.get("albedo_map_possible"):
            return []
        return [model]
