"""The diffuse terms a fit can use: `Lambertian` and every subclass of it that names itself.

A diffuse lobe is a `Lambertian` (its weight is the albedo `rho_tilde`, per surface point
under the albedo map) whose angular shape may have parameters of its own, declared as its
fields after `weight` with a name and a finite domain (`named`, `domain`). Setting the class
attribute `diffuse_name` offers it to `ctjax fit`, `calibrate-light` and `evaluate`
(`--diffuse NAME`): its file is found in `ctjax.lobes` by `diffuse_lobes`, and nothing else
has to be edited.
"""

import dataclasses
import importlib
import math
import pkgutil

from .._errors import CtjaxError
from ._lambertian import Lambertian


def _subclasses(cls):
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)


def diffuse_lobes() -> dict[str, type[Lambertian]]:
    """Every diffuse lobe in `ctjax.lobes` by its `diffuse_name` (`"lambertian"` first)."""
    package = importlib.import_module(__package__)
    for info in pkgutil.iter_modules(package.__path__):
        importlib.import_module(f"{__package__}.{info.name}")
    found = {Lambertian.diffuse_name: Lambertian}
    for cls in _subclasses(Lambertian):
        name = vars(cls).get("diffuse_name")
        if name is not None and cls.__module__.startswith(__package__):
            found[name] = cls
    return found


def diffuse_lobe_named(name: str) -> type[Lambertian]:
    """The diffuse lobe called `name` (see `diffuse_lobes`); a clear error otherwise."""
    lobes = diffuse_lobes()
    if name not in lobes:
        raise CtjaxError(f"unknown diffuse term {name!r}: one of {', '.join(lobes)}")
    return lobes[name]


def diffuse_parameters(lobe: type[Lambertian]) -> tuple[tuple[str, float, float], ...]:
    """`(paper name, lo, hi)` of each parameter of `lobe`'s shape: its fields after `weight`,
    in order, with their domains (a search needs both ends finite)."""
    out = []
    for field in dataclasses.fields(lobe):
        if field.name == "weight":
            continue
        name = field.metadata.get("name", field.name)
        lo, hi = field.metadata.get("domain", (-math.inf, math.inf))
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise CtjaxError(
                f"{lobe.__name__}.{field.name}: a diffuse lobe's parameter needs a finite "
                f"domain to be searched (metadata=domain(lo, hi)), got ({lo}, {hi})"
            )
        out.append((name, lo, hi))
    return tuple(out)


def with_diffuse_lobe(brdf, lobe: type[Lambertian], shape=None):
    """`brdf` (a `BRDF`) with its Lambertian lobe replaced by `lobe(weight, *shape)`, the
    weight kept; `shape` by default the middle of each parameter's domain (a fit's start).
    `Lambertian` gives `brdf` itself."""
    if lobe is Lambertian:
        return brdf
    if shape is None:
        shape = [(lo + hi) / 2 for _, lo, hi in diffuse_parameters(lobe)]
    return type(brdf)(
        *(lobe(each.weight, *shape) if type(each) is Lambertian else each for each in brdf.lobes)
    )
