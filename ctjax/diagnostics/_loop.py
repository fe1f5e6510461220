"""The diagnose loop: add the missing effect, diagnose again, until nothing is missing.

The mission's "see where the model fails, learn which physical effect is missing, add it
and watch the error fall", run to its end: each step is a `diagnose` of the base model
with every verdict so far added (`add`), so its base held-out RMSE is the error of the
model grown so far. The loop stops at the verdict "none", at a verdict it has already
added (no progress left to make), or after `max_rounds` steps.

The capture is prepared once (`Prepared`: its observations and held-out splits, the same
in every step), and step k+1's base model is step k's verdict candidate (`next_base`: the
base with the verdict added, fitted on the same calibration data from the same starts as a
refit would be, then judged on the same held-out data; refitted where the candidate held
per-frame parameters at its base's values or was reported as its base).
"""

import dataclasses
import time
from pathlib import Path

from ._diagnose import Prepared, diagnose, next_base
from ._diagnosis import Diagnosis


@dataclasses.dataclass
class DiagnosisLoop:
    """Every step's `Diagnosis` (step k's base has the first k verdicts added), the
    effects added in order, why the loop stopped and the seconds it took."""

    steps: list[Diagnosis]
    added: list[str]
    stopped: str
    seconds: float

    @property
    def final(self) -> Diagnosis:
        return self.steps[-1]

    def to_json(self) -> dict:
        return {
            "added": list(self.added),
            "stopped": self.stopped,
            "steps": [
                {
                    "added_before": list(self.added[:k]),
                    "base_rmse": step.base_rmse,
                    "noise_floor": step.noise_floor,
                    "over_noise_floor": step.base_rmse / step.noise_floor
                    if step.noise_floor > 0
                    else None,
                    "verdict": step.verdict,
                    "verdict_status": step.verdict_status,
                    "albedo": step.base.details.get("albedo"),
                    "seconds": round(step.seconds, 2),
                    **{
                        key: value
                        for key, value in step.to_json().items()
                        if key in ("candidates", "leading", "close")
                    },
                }
                for k, step in enumerate(self.steps)
            ],
            "final_verdict": self.final.verdict,
            "seconds": round(self.seconds, 2),
        }


def diagnose_loop(capture, *, max_rounds: int = 5, progress=None, **options) -> DiagnosisLoop:
    """`diagnose` (same `options`) with its verdict added, again and again (see the
    module doc). The albedo model the first step chose (`"map"` or `"uniform"`) is kept
    for the next steps."""
    say = progress or (lambda message: None)
    if int(max_rounds) != max_rounds or max_rounds < 1:
        from .._errors import ParameterError

        raise ParameterError(f"max_rounds must be a positive integer, got {max_rounds}")
    started = time.perf_counter()
    effects = list(options.pop("add", ()))  # passed to diagnose's `add`
    added = []  # every verdict taken, in order (albedo_texture: the map, not an `add`)
    steps, stopped, base = [], "", None
    settings = {
        k: options[k]
        for k in ("calibration", "max_samples", "heldout_samples", "seed")
        if k in options
    }
    prepared = Prepared(capture, **settings)
    while len(steps) < max_rounds:
        say(f"step {len(steps) + 1}: diagnosing with {', '.join(added) or 'nothing'} added")
        step = diagnose(prepared, add=tuple(effects), progress=progress, base=base, **options)
        steps.append(step)
        say(
            f"step {len(steps)}: base held-out RMSE {step.base_rmse:.2f} levels "
            f"({step.base_rmse / step.noise_floor:.2f}x the noise floor {step.noise_floor:.2f}), "
            f"verdict {step.verdict}, {step.seconds:.0f} s"
        )
        options["albedo"] = step.base.details.get("albedo", options.get("albedo"))
        if step.verdict == "none":
            stopped = "verdict none: no candidate lowers the held-out RMSE by 3%"
            break
        if step.verdict in added:
            stopped = f"verdict {step.verdict} again (already added)"
            break
        added.append(step.verdict)
        base = next_base(step)
        if step.verdict == "albedo_texture":
            options["albedo"] = "map"  # the texture is the albedo map itself
        else:
            effects.append(step.verdict)
    else:
        stopped = f"after {max_rounds} step(s) (the budget), verdict {steps[-1].verdict}"
    return DiagnosisLoop(steps, added, stopped, time.perf_counter() - started)


def plot_loop(loop: DiagnosisLoop, path: Path) -> Path:
    """The held-out RMSE step by step against the noise floor: the error falling as each
    missing effect is added."""
    from .._residuals import figure

    fig = figure(figsize=(6.4, 3.8))
    ax = fig.subplots()
    x = list(range(len(loop.steps)))
    labels = ["paper"] + [f"+ {a}" for a in loop.added[: len(loop.steps) - 1]]
    ax.plot(x, [s.base_rmse for s in loop.steps], "o-", label="held-out RMSE (base model)")
    ax.plot(x, [s.noise_floor for s in loop.steps], "s--", color="grey", label="noise floor")
    best = [c.heldout_rmse if (c := _verdict(s)) else s.base_rmse for s in loop.steps]
    ax.plot(x, best, "^:", color="tab:green", label="with the verdict added")
    ax.set_xticks(x, labels, rotation=20, ha="right")
    ax.set_ylabel("RGB RMSE (8-bit levels)")
    ax.set_ylim(bottom=0)
    ax.set_title(f"diagnose --loop: {loop.stopped}", fontsize=9)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=90)
    return path


def _verdict(step: Diagnosis):
    for c in step.candidates:
        if c.details["effect"] == step.verdict:
            return c
    return None
