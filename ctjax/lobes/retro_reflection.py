"""A retro-reflection lobe: light sent back towards where it came from (L = V).

Retro-reflective materials (road signs, tapes; wet tissue at grazing angles, to a lesser
degree) show a narrow peak when the light is beside the viewer, which a microfacet lobe
centred on the mirror direction does not have. On the CEA's measured retro-reflective tape
(`../shared/data/retro-gray-tape.dat`) this lobe beside Cook-Torrance lowers the RMSE from
6.31 to 1.47 1/sr; ALTA's retro-Beckmann does worse (`notebooks/03_measured_retro.ipynb`).

This file is the whole lobe: the physics for one pixel, its parameters' domains and names
(so the fitters keep them physical and every JSON shows them), and its candidate for
`ctjax diagnose`. Nothing else in ctjax was edited to add it.
"""

import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_lobe
from .._convert import POSITIVE, as_float, as_rgb, check_positive, check_shape, named
from .._typing import Array, Float, Scalar
from .._vector import Vec3
from ._lobe import AbstractLobe


class RetroReflection(AbstractLobe):
    """`weight * exp(-(1 - L.V) / width) * (N.L)^(falloff + 1)`: a peak of angular width
    about `sqrt(2 width)` radians around L = V, whose height falls with incidence as
    `cos^falloff` (cosine factor included), 0 unless N.L > 0 and N.V > 0.

    **Arguments:**

    - `weight`: the peak's height per colour channel (linear units), >= 0.
    - `width`: 1 - cos of the peak's half-width, > 0 (1e-3: about 2.6 degrees).
    - `falloff`: the exponent of the peak's fall with incidence, >= 0.
    """

    weight: Float[Array, "3"] = eqx.field(converter=as_rgb, metadata=named("retro", POSITIVE))
    width: Float[Array, ""] = eqx.field(converter=as_float, metadata=named("retro_width", POSITIVE))
    falloff: Float[Array, ""] = eqx.field(
        converter=as_float, default=1.0, metadata=named("retro_falloff", POSITIVE)
    )

    def __check_init__(self):
        check_shape("RetroReflection", "weight", self.weight, (3,))
        check_positive("RetroReflection", "weight", self.weight, allow_zero=True)
        check_shape("RetroReflection", "width", self.width, ())
        check_positive("RetroReflection", "width", self.width)
        check_shape("RetroReflection", "falloff", self.falloff, ())
        check_positive("RetroReflection", "falloff", self.falloff, allow_zero=True)

    def radiance(self, normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
        n_dot_l = normal @ light
        lit = (n_dot_l > 0) & (normal @ view > 0)
        # cos^(k+1) as exp((k+1) log cos), guarded where unlit so gradients stay finite.
        cosine = jnp.where(lit, n_dot_l, 1.0)
        peak = jnp.exp(-(1 - light @ view) / self.width)
        return jnp.where(lit, peak * jnp.exp((self.falloff + 1) * jnp.log(cosine)), 0.0)


class RetroReflectionCandidate(AbstractCandidate):
    """A retro-reflection peak beside the model's lobes, from a narrow and a broad start."""

    name = "retro_reflection"

    def __call__(self, model, context):
        weight = 0.1 * jnp.max(model.brdf.weights, axis=0)
        return [
            with_lobe(model, RetroReflection(weight, jnp.asarray(width), jnp.asarray(1.0)))
            for width in (1e-3, 1e-2)
        ]
