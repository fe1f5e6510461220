"""How a physical effect declares itself to the diagnostics: a candidate.

A candidate turns a fitted model into one or a few starting models that include its effect
(several where the new parameter has more than one plausible basin); `ctjax diagnose` refits
each and ranks them by held-out error. Each effect's candidate lives in the same module as
the effect (`lights/_inverse_square.py` holds `InverseSquare` and `InverseSquareCandidate`),
and the diagnostics find every candidate defined in ctjax's `lobes`, `lights` and `effects`
packages by themselves: a new effect or lobe is one file, and nothing else is edited.

It sits at the bottom of the package (it needs only equinox), so physics modules can declare
their candidates without importing anything above them.
"""

import abc
from typing import TYPE_CHECKING

import equinox as eqx

if TYPE_CHECKING:
    from ._model import ShadingModel


class AbstractCandidate(eqx.Module):
    """Adds one effect to a model. `name` is what `ctjax diagnose --add` and the JSON use."""

    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def __call__(self, model: "ShadingModel", context: dict) -> list["ShadingModel"]:
        """Starting models with the effect added (`context`: e.g. `median_depth_mm`)."""


def with_falloff(model: "ShadingModel", falloff) -> "ShadingModel":
    """`model` with one more falloff factor on its light."""
    return eqx.tree_at(lambda m: m.light.falloff, model, (*model.light.falloff, falloff))


def with_lobe(model: "ShadingModel", lobe) -> "ShadingModel":
    """`model` with one more lobe in its BRDF."""
    return eqx.tree_at(lambda m: m.brdf, model, type(model.brdf)(*model.brdf.lobes, lobe))


def with_lobes(model: "ShadingModel", change) -> "ShadingModel":
    """`model` with `change(lobe)` applied to every lobe of its BRDF."""
    lobes = tuple(change(lobe) for lobe in model.brdf.lobes)
    return eqx.tree_at(lambda m: m.brdf.lobes, model, lobes)


def with_factor(model: "ShadingModel", factor) -> "ShadingModel":
    """`model` with one more factor on every microfacet lobe (every lobe with `factors`)."""

    def add(lobe):
        if not hasattr(lobe, "factors"):
            return lobe
        return eqx.tree_at(lambda l: l.factors, lobe, (*lobe.factors, factor))

    return with_lobes(model, add)


def with_effect(model: "ShadingModel", effect, *, first: bool = False) -> "ShadingModel":
    """`model` with one more image effect, last (or `first`: before the others, e.g. an
    ambient radiance that adds before the camera's response)."""
    effects = (effect, *model.effects) if first else (*model.effects, effect)
    return eqx.tree_at(lambda m: m.effects, model, effects)
