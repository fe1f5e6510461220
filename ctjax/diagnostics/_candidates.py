"""The candidate effects the diagnostics try, found where the effects are defined.

Every concrete `AbstractCandidate` in ctjax's `lobes`, `lights` and `effects` packages is a
candidate (each lives beside its effect: `InverseSquareCandidate` in
`lights/_inverse_square.py`); a new file there with a lobe and its candidate is picked up
with no edit here. A user's own candidate is passed in the `candidates` tuple.
"""

from .._candidate import AbstractCandidate as AbstractCandidate
from .._candidate import discover_candidates as discover_candidates
from .._errors import CtjaxError

CANDIDATES: tuple[AbstractCandidate, ...] = discover_candidates()


def candidate(name: str, candidates=CANDIDATES) -> AbstractCandidate:
    """The candidate called `name`."""
    for c in candidates:
        if c.name == name:
            return c
    known = ", ".join(dict.fromkeys(c.name for c in candidates))  # each once, in order
    raise CtjaxError(f"unknown effect {name!r}; known: {known}")
