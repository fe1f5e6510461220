"""How a physical effect declares itself: a candidate, for the diagnostics and for synth.

A candidate turns a fitted model into one or a few starting models that include its effect
(several where the new parameter has more than one plausible basin); `ctjax diagnose` refits
each and ranks them by held-out error. It may also say how `ctjax synth` hides the effect in
a synthetic capture: its command-line option (`add_synth_arguments`, `synth_value`) and the
effect with its true parameters (`synthesize`). Each effect's candidate lives in the same
module as the effect (`lights/_inverse_square.py` holds `InverseSquare` and
`InverseSquareCandidate`); `discover_candidates` finds every candidate defined in ctjax's
`lobes`, `lights` and `effects` packages: a new effect or lobe is one file, and nothing else
(synth, the CLI, the JSON, the candidate list) is edited.

It sits at the bottom of the package (it needs only equinox), so physics modules can declare
their candidates without importing anything above them.
"""

import abc
import importlib
import pkgutil
from typing import TYPE_CHECKING, Any

import equinox as eqx

if TYPE_CHECKING:
    from ._model import ShadingModel


class AbstractCandidate(eqx.Module):
    """Adds one effect to a model. `name` is what `ctjax diagnose --add` and the JSON use."""

    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def __call__(self, model: "ShadingModel", context: dict) -> list["ShadingModel"]:
        """Starting models with the effect added (`context`: e.g. `median_depth_mm`)."""

    # `ctjax synth`: optional. A candidate without them is not offered by synth.

    def add_synth_arguments(self, group) -> None:
        """Add the effect's options to an argparse group (`--inverse-square`...)."""

    def synth_value(self, args) -> Any:
        """The effect's value from the parsed options, None when it is off."""
        return None

    def synthesize(self, model: "ShadingModel", value: Any, context: dict) -> "ShadingModel":
        """The scene `model` with the effect at its true `value` (`context`: the capture's
        `working_distance_mm`)."""
        raise NotImplementedError(f"{self.name} cannot be synthesised")


_PACKAGES = ("ctjax.lights", "ctjax.lobes", "ctjax.effects")


def _subclasses(cls):
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)


def discover_candidates() -> tuple[AbstractCandidate, ...]:
    """One instance of every candidate defined in ctjax's physics packages, by name."""
    for package in _PACKAGES:
        module = importlib.import_module(package)
        for info in pkgutil.iter_modules(module.__path__):
            importlib.import_module(f"{package}.{info.name}")
    found = {
        cls.name: cls
        for cls in _subclasses(AbstractCandidate)
        if cls.__module__.startswith(_PACKAGES) and "name" in vars(cls)
    }
    return tuple(found[name]() for name in sorted(found))


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
