"""The candidate effects the diagnostics try, found where the effects are defined.

Every concrete `AbstractCandidate` in ctjax's `lobes`, `lights` and `effects` packages is a
candidate (each lives beside its effect: `InverseSquareCandidate` in
`lights/_inverse_square.py`); a new file there with a lobe and its candidate is picked up
with no edit here. A user's own candidate is passed in the `candidates` tuple.
"""

import importlib
import pkgutil

from .._candidate import AbstractCandidate
from .._errors import CtjaxError

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


CANDIDATES: tuple[AbstractCandidate, ...] = discover_candidates()


def candidate(name: str, candidates=CANDIDATES) -> AbstractCandidate:
    """The candidate called `name`."""
    for c in candidates:
        if c.name == name:
            return c
    raise CtjaxError(f"unknown effect {name!r}; known: {', '.join(c.name for c in candidates)}")
