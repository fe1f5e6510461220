"""Where the model fails, and which physical effect is missing (`ctjax diagnose`).

The base model is the paper's (Lambertian + Beckmann specular with constant F, the light at
the camera centre, constant intensity). It is fitted on the calibration frames and judged on
held-out frames; then every candidate effect is added in turn, refitted, and ranked by its
held-out RMSE. The noise floor is estimated from the data itself (differences of
neighbouring residuals, where any smooth model error cancels), so the user knows when the
model explains everything there is to explain.
"""

import dataclasses
import time

import numpy as np

from .._errors import CtjaxError
from .._result import Estimate
from ..fitting import (
    ShadingModel,
    fit_model,
    free_parameters,
    paper_model,
    pixel_columns,
    pixel_predict,
    roughness_variants,
)
from ..heldout import HeldOut, median_depth_mm
from ..io import Capture
from ..observations import Observations
from ._candidates import CANDIDATES, AbstractCandidate, candidate

# A candidate "explains the data" when it lowers the held-out RMSE by at least this
# fraction, and the base model is measurably above the noise floor.
MATERIAL_IMPROVEMENT = 0.03
ABOVE_NOISE = 1.05


@dataclasses.dataclass
class Diagnosis:
    """The base model and every candidate, each an `Estimate` judged on held-out frames.

    A candidate's `details` hold its `effect` (name), its `improvement` (fraction of the
    base's held-out RMSE) and the `params` it introduced; candidates are sorted best first.
    """

    base: Estimate
    noise_floor: float
    candidates: list[Estimate]
    verdict: str
    seconds: float

    @property
    def base_rmse(self) -> float:
        return self.base.heldout_rmse

    @property
    def calibration_frames(self) -> list[int]:
        return self.base.frames["calibration"]

    @property
    def heldout_frames(self) -> list[int]:
        return self.base.frames["heldout"]

    def to_json(self) -> dict:
        return {
            "base_rmse": self.base_rmse,
            "noise_floor": self.noise_floor,
            "candidates": [
                {
                    "effect": c.details["effect"],
                    "heldout_rmse": c.heldout_rmse,
                    "improvement": c.details["improvement"],
                    "params": c.details["params"],
                }
                for c in self.candidates
            ],
            "verdict": self.verdict,
        }

    @property
    def best_model(self) -> ShadingModel:
        for c in self.candidates:
            if c.details["effect"] == self.verdict:
                return c.model
        return self.base.model


def _new_parameters(base: ShadingModel, fitted: ShadingModel) -> dict:
    """Values of the parameters the candidate introduced (names not in the base model)."""
    known = {p.name for p in free_parameters(base)}
    out = {}
    for p in free_parameters(fitted):
        if p.name not in known:
            value = np.asarray(p.get(fitted))
            out[p.name] = value.tolist() if value.ndim else float(value)
    return out


def _fit(starts, samples, max_steps) -> Estimate:
    starts = [variant for start in starts for variant in roughness_variants(start)]
    return fit_model(
        starts, samples, pixel_predict, columns=pixel_columns, max_steps=max_steps, refine=3
    )


def _base_model(heldout, add, candidates, context, max_steps, say) -> Estimate:
    say(f"fitting the base model on frames {heldout.calibration} ({len(heldout.train)} pixels)")
    base_starts = [paper_model(1.0, 0.3, s) for s in (0.08, 0.2, 0.45)]
    base = _fit(base_starts, heldout.train, max_steps)
    for extra in add:
        effect = candidate(extra, (*candidates, *CANDIDATES)) if isinstance(extra, str) else extra
        starts = effect(base.model, context)
        if not starts:
            raise CtjaxError(f"effect {effect.name} does not apply to this model")
        say(f"adding {effect.name} to the base model")
        base = _fit(starts, heldout.train, max_steps)
    return heldout.judge(base)


def diagnose(
    capture: "Capture | Observations",
    *,
    calibration: int | None = None,
    add: tuple[str | AbstractCandidate, ...] = (),
    candidates: tuple[AbstractCandidate, ...] = CANDIDATES,
    max_samples: int = 12_000,
    heldout_samples: int = 40_000,
    max_steps: int = 80,
    seed: int = 0,
    progress=None,
) -> Diagnosis:
    """Fit the paper's model (plus `add`) and rank every candidate effect by held-out RMSE."""
    started = time.perf_counter()
    say = progress or (lambda message: None)
    capture = Observations.of(capture)
    if not capture.capture.has_geometry or any(f.depth is None for f in capture.frames):
        raise CtjaxError(f"{capture.root}: diagnose needs depth for every frame (depth/NAME.npy)")
    heldout = HeldOut.split(
        capture, calibration, max_samples=max_samples, heldout_samples=heldout_samples, seed=seed
    )
    context = {"median_depth_mm": median_depth_mm(capture)}
    base = _base_model(heldout, add, candidates, context, max_steps, say)
    noise = base.noise_floor
    say(f"base model: held-out RMSE {base.heldout_rmse:.2f} levels, noise floor {noise:.2f}")

    added = {e if isinstance(e, str) else e.name for e in add}
    results = []
    for effect in candidates:
        if effect.name in added:
            continue
        starts = effect(base.model, context)
        if not starts:
            continue
        fit = _fit(starts, heldout.train, max_steps)
        if not np.isfinite(fit.cost):
            continue
        fit = heldout.judge(fit, noise_floor=False)
        improvement = (base.heldout_rmse - fit.heldout_rmse) / base.heldout_rmse
        fit.details = {
            "effect": effect.name,
            "improvement": improvement,
            "params": _new_parameters(base.model, fit.model),
        }
        results.append(fit)
        say(
            f"  + {effect.name:<22} held-out RMSE {fit.heldout_rmse:6.2f} "
            f"({100 * improvement:+.1f}%)" + ("" if fit.converged else f" [{fit.status.name}]")
        )
    results.sort(key=lambda c: c.heldout_rmse)
    if results and results[0].heldout_rmse < base.heldout_rmse:
        # Every estimate of the noise is biased up by what the model misses: the best
        # model gives the tightest one.
        noise = min(noise, heldout.noise_floor(results[0].model))
    verdict = "none"
    if (
        results
        and base.heldout_rmse > ABOVE_NOISE * noise
        and results[0].details["improvement"] >= MATERIAL_IMPROVEMENT
    ):
        verdict = results[0].details["effect"]
    return Diagnosis(base, noise, results, verdict, time.perf_counter() - started)
