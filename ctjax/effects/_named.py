"""Image effects by name: what `--effects frame_exposure vignetting` asks a command for.

A name is an image effect's candidate (`AbstractCandidate.name`, as `ctjax diagnose` lists
them); the effect is its candidate's first start for the model at hand, so its parameters
start where the diagnostics would start them (no exposure change, no vignetting). Names of
candidates that change the light or the BRDF (a falloff, a lobe) are refused: a command
that takes image effects fits its own light and lobes.
"""

from collections.abc import Sequence

import jax

from .._candidate import AbstractCandidate, discover_candidates, with_effect
from .._errors import CtjaxError
from ._effect import AbstractImageEffect


def image_effect_names() -> tuple[str, ...]:
    """The names of the candidates that add an image effect (and nothing else)."""
    return tuple(c.name for c in discover_candidates() if _is_image_effect(type(c)))


def _is_image_effect(cls) -> bool:
    return cls.__module__.startswith(__package__ + ".")


def image_effects(
    effects: Sequence[str | AbstractCandidate | AbstractImageEffect], model, context: dict
) -> tuple[AbstractImageEffect, ...]:
    """`effects` as image effects, in order: an `AbstractImageEffect` as it is, a candidate
    (or its name) as the effect its first start adds to `model` with the effects before it
    (`context`: `Observations.candidate_context()`)."""
    known = {c.name: c for c in discover_candidates()}
    out = []
    for effect in effects:
        if isinstance(effect, str):
            if effect not in known or not _is_image_effect(type(known[effect])):
                names = ", ".join(image_effect_names())
                what = "not an image effect" if effect in known else "unknown"
                raise CtjaxError(f"effect {effect!r}: {what}; image effects: {names}")
            effect = known[effect]
        if isinstance(effect, AbstractCandidate):
            effect = _added(effect, model, context)
        if not isinstance(effect, AbstractImageEffect):
            raise CtjaxError(
                "effects must be image effects, their candidates or their names, got "
                f"{type(effect).__name__}"
            )
        out.append(effect)
        model = with_effect(model, effect)
    return tuple(out)


def _added(candidate: AbstractCandidate, model, context: dict) -> AbstractImageEffect:
    """The one image effect `candidate`'s first start adds to `model`."""
    starts = candidate(model, context)
    if not starts:
        raise CtjaxError(f"effect {candidate.name} does not apply to this model (already in it?)")
    start = starts[0]
    same = all(
        jax.tree.structure(getattr(start, part)) == jax.tree.structure(getattr(model, part))
        for part in ("brdf", "light")
    )
    before = [type(e) for e in model.effects]
    after = list(start.effects)
    for index in range(len(after)):
        if same and [type(e) for e in after[:index] + after[index + 1 :]] == before:
            return after[index]
    raise CtjaxError(f"effect {candidate.name} is not an image effect: it changes the model")
