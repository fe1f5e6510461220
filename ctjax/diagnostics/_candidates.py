"""Candidate effects: how to add each missing physical effect to a model, by name.

A candidate turns a fitted model into one or a few starting models that include the effect
(several starts where the new parameter has more than one plausible basin); the diagnostics
refit each and rank them by held-out error. A user's own effect is one more small class
with a `name` and `__call__`, passed in the `candidates` tuple: nothing here is edited.
"""

import abc

import equinox as eqx
import jax.numpy as jnp

from ..effects import Ambient, CameraGamma
from ..fitting import ShadingModel
from ..lights import ColocatedLight, InverseSquare, PointLight, SpotFalloff
from ..lobes import GGX, Beckmann, GeometricAttenuation, SchlickFresnel, Specular


class AbstractCandidate(eqx.Module):
    """Adds one effect to a model. `name` is what `ctjax diagnose --add` and the JSON use."""

    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def __call__(self, model: ShadingModel, context: dict) -> list[ShadingModel]:
        """Starting models with the effect added (`context`: e.g. the median depth, mm)."""


def _specular_lobes(model: ShadingModel) -> list[int]:
    return [i for i, lobe in enumerate(model.brdf.lobes) if isinstance(lobe, Specular)]


def _with_falloff(model: ShadingModel, falloff) -> ShadingModel:
    return eqx.tree_at(lambda m: m.light.falloff, model, (*model.light.falloff, falloff))


def _with_factor(model: ShadingModel, factor) -> ShadingModel:
    for index in _specular_lobes(model):
        model = eqx.tree_at(
            lambda m, i=index: m.brdf.lobes[i].factors,
            model,
            (*model.brdf.lobes[index].factors, factor),
        )
    return model


class InverseSquareCandidate(AbstractCandidate):
    name = "inverse_square"

    def __call__(self, model, context):
        return [_with_falloff(model, InverseSquare(context["median_depth_mm"]))]


class SpotFalloffCandidate(AbstractCandidate):
    name = "spot_falloff"

    def __call__(self, model, context):
        return [_with_falloff(model, SpotFalloff(k)) for k in (1.0, 4.0)]


class LightOffsetCandidate(AbstractCandidate):
    name = "light_offset"

    def __call__(self, model, context):
        light = model.light
        if not isinstance(light, ColocatedLight):
            return []
        offsets = [(3.0, 0, 0), (-3.0, 0, 0), (0, 3.0, 0), (0, -3.0, 0)]
        return [
            eqx.tree_at(
                lambda m: m.light, model, PointLight(jnp.asarray(o, float), falloff=light.falloff)
            )
            for o in offsets
        ]


class SecondLobeCandidate(AbstractCandidate):
    name = "second_lobe"

    def __call__(self, model, context):
        specular = [model.brdf.lobes[i] for i in _specular_lobes(model)]
        if not specular:
            return []
        first = specular[0]
        sigma = getattr(first.distribution, "sigma", jnp.asarray(0.2))
        starts = []
        for scale in (0.4, 2.5):
            lobe = Specular(
                0.3 * first.weight, Beckmann(jnp.clip(sigma * scale, 0.02, 0.9)), first.factors
            )
            brdf = type(model.brdf)(*model.brdf.lobes, lobe)
            starts.append(eqx.tree_at(lambda m: m.brdf, model, brdf))
        return starts


class CameraGammaCandidate(AbstractCandidate):
    name = "camera_gamma"

    def __call__(self, model, context):
        return [
            eqx.tree_at(lambda m: m.effects, model, (*model.effects, CameraGamma(g)))
            for g in (1.3, 2.2)
        ]


class AmbientCandidate(AbstractCandidate):
    name = "ambient"

    def __call__(self, model, context):
        # Ambient radiance adds before the camera response: first in the effects.
        return [eqx.tree_at(lambda m: m.effects, model, (Ambient(0.01), *model.effects))]


class FresnelSchlickCandidate(AbstractCandidate):
    name = "fresnel_schlick"

    def __call__(self, model, context):
        # Cook-Torrance's V.H, and the N.V shortcut that many renderers use.
        return [_with_factor(model, SchlickFresnel(0.05, cosine)) for cosine in ("half", "normal")]


class GeometricAttenuationCandidate(AbstractCandidate):
    name = "geometric_attenuation"

    def __call__(self, model, context):
        return [_with_factor(model, GeometricAttenuation())]


class GGXCandidate(AbstractCandidate):
    name = "ggx"

    def __call__(self, model, context):
        for index in _specular_lobes(model):
            distribution = model.brdf.lobes[index].distribution
            if isinstance(distribution, Beckmann):
                model = eqx.tree_at(
                    lambda m, i=index: m.brdf.lobes[i].distribution, model, GGX(distribution.sigma)
                )
        return [model]


CANDIDATES: tuple[AbstractCandidate, ...] = (
    InverseSquareCandidate(),
    SpotFalloffCandidate(),
    LightOffsetCandidate(),
    SecondLobeCandidate(),
    CameraGammaCandidate(),
    AmbientCandidate(),
    FresnelSchlickCandidate(),
    GeometricAttenuationCandidate(),
    GGXCandidate(),
)


def candidate(name: str, candidates=CANDIDATES) -> AbstractCandidate:
    """The candidate called `name`."""
    for c in candidates:
        if c.name == name:
            return c
    from .._errors import CtjaxError

    raise CtjaxError(f"unknown effect {name!r}; known: {', '.join(c.name for c in candidates)}")
