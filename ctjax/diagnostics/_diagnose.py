"""Where the model fails, and which physical effect is missing (`ctjax diagnose`).

The base model is the paper's (Lambertian + Beckmann specular with constant F, the light at
the camera centre, constant intensity). It is fitted on the calibration frames and judged on
held-out frames; then every candidate effect is added in turn, refitted, and ranked by its
held-out RMSE. The noise floor is estimated from the data itself (differences of
neighbouring residuals, where any smooth model error cancels), so the user knows when the
model explains everything there is to explain.
"""

import dataclasses
import math
import time

import numpy as np

from .._errors import CtjaxError
from ..fitting import (
    FitResult,
    ShadingModel,
    capture_samples,
    fit_model,
    free_parameters,
    paper_model,
    pixel_columns,
    pixel_predict,
    rmse_levels,
    roughness_variants,
)
from ..fitting._samples import usable_mask
from ..io import Capture
from ._candidates import CANDIDATES, AbstractCandidate, candidate

# A candidate "explains the data" when it lowers the held-out RMSE by at least this
# fraction, and the base model is measurably above the noise floor.
MATERIAL_IMPROVEMENT = 0.03
ABOVE_NOISE = 1.05


@dataclasses.dataclass
class CandidateResult:
    effect: str
    fit: FitResult
    heldout_rmse: float
    improvement: float
    params: dict


@dataclasses.dataclass
class Diagnosis:
    base: FitResult
    base_rmse: float
    noise_floor: float
    candidates: list[CandidateResult]
    verdict: str
    calibration_frames: list[int]
    heldout_frames: list[int]
    seconds: float

    def to_json(self) -> dict:
        return {
            "base_rmse": self.base_rmse,
            "noise_floor": self.noise_floor,
            "candidates": [
                {
                    "effect": c.effect,
                    "heldout_rmse": c.heldout_rmse,
                    "improvement": c.improvement,
                    "params": c.params,
                }
                for c in self.candidates
            ],
            "verdict": self.verdict,
        }

    @property
    def best_model(self) -> ShadingModel:
        for c in self.candidates:
            if c.effect == self.verdict:
                return c.fit.model
        return self.base.model


def split_frames(
    count: int, calibration: int | None = None, *, source=None
) -> tuple[list[int], list[int]]:
    """The first frames calibrate, the rest are held out (default: 60% / 40%).

    `source` (the capture's folder) names the capture in the errors.
    """
    where = f"{source}: " if source is not None else ""
    if count < 2:
        raise CtjaxError(
            f"{where}needs at least 2 frames (calibration and held-out), the capture has {count}"
        )
    if calibration is None:
        calibration = min(count - 1, max(1, math.ceil(0.6 * count)))
    if not 1 <= calibration < count:
        raise CtjaxError(
            f"{where}--calib (calibration frames) must be between 1 and {count - 1} for "
            f"{count} frames, got {calibration}"
        )
    return list(range(calibration)), list(range(calibration, count))


def _new_parameters(base: ShadingModel, fitted: ShadingModel) -> dict:
    """Values of the parameters the candidate introduced (names not in the base model)."""
    known = {p.name for p in free_parameters(base)}
    out = {}
    for p in free_parameters(fitted):
        if p.name not in known:
            value = np.asarray(p.get(fitted))
            out[p.name] = value.tolist() if value.ndim else float(value)
    return out


def noise_floor_levels(capture: Capture, frames: list[int], model: ShadingModel) -> float:
    """Pixel noise (8-bit levels) from second differences of residuals along rows and columns.

    `r[i-1] - 2 r[i] + r[i+1]` cancels any residual that varies linearly over three pixels
    (a smooth model error, even a large one), and has variance 6 sigma^2 for independent
    noise. Outliers (highlights' edges) are clipped iteratively at 4 standard deviations;
    not the median absolute deviation, which is biased here because the second difference
    of a smooth image quantised to 8 bits takes nearly integer values.
    """
    differences = []
    for index in frames:
        frame = capture.frames[index]
        rendered = np.asarray(model.render(capture.camera, frame.normals, frame.depth))
        residual = (rendered - frame.image) * 255
        usable = usable_mask(frame)
        for r, u in ((residual, usable), (np.swapaxes(residual, 0, 1), usable.T)):
            second = r[:-2] - 2 * r[1:-1] + r[2:]
            both = u[:-2] & u[1:-1] & u[2:]
            differences.append(second[both].reshape(-1))
    d = np.concatenate(differences)
    if d.size < 100:
        raise CtjaxError("too few usable neighbouring pixels to estimate the noise floor")
    kept = d
    for _ in range(5):
        spread = np.std(kept)
        kept = d[np.abs(d - np.mean(kept)) < 4 * spread]
    # A Gaussian clipped at 4 sigma keeps 99.9% of its variance.
    return float(np.std(kept) / math.sqrt(6))


def _fit(starts, samples, max_steps):
    starts = [variant for start in starts for variant in roughness_variants(start)]
    return fit_model(
        starts, samples, pixel_predict, columns=pixel_columns, max_steps=max_steps, refine=3
    )


def diagnose(
    capture: Capture,
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
    if not capture.has_geometry or any(f.depth is None for f in capture.frames):
        raise CtjaxError(f"{capture.root}: diagnose needs depth for every frame (depth/NAME.npy)")
    calib, heldout = split_frames(len(capture), calibration, source=capture.root)
    train = capture_samples(capture, calib, max_samples=max_samples, seed=seed)
    test = capture_samples(capture, heldout, max_samples=heldout_samples, seed=seed + 1)
    depth = np.concatenate([capture.frames[i].depth[usable_mask(capture.frames[i])] for i in calib])
    context = {"median_depth_mm": float(np.median(depth))}

    say(f"fitting the base model on frames {calib} ({len(train)} pixels)")
    base_starts = [paper_model(1.0, 0.3, s) for s in (0.08, 0.2, 0.45)]
    base = _fit(base_starts, train, max_steps)
    for extra in add:
        effect = candidate(extra, (*candidates, *CANDIDATES)) if isinstance(extra, str) else extra
        starts = effect(base.model, context)
        if not starts:
            raise CtjaxError(f"effect {effect.name} does not apply to this model")
        say(f"adding {effect.name} to the base model")
        base = _fit(starts, train, max_steps)
    added = {e if isinstance(e, str) else e.name for e in add}
    base_rmse = float(rmse_levels(base.model, test, pixel_predict))
    noise = noise_floor_levels(capture, heldout, base.model)
    say(f"base model: held-out RMSE {base_rmse:.2f} levels, noise floor {noise:.2f}")

    results = []
    for effect in candidates:
        if effect.name in added:
            continue
        starts = effect(base.model, context)
        if not starts:
            continue
        fit = _fit(starts, train, max_steps)
        if not np.isfinite(float(fit.cost)):
            continue
        heldout_rmse = float(rmse_levels(fit.model, test, pixel_predict))
        improvement = (base_rmse - heldout_rmse) / base_rmse
        results.append(
            CandidateResult(
                effect.name, fit, heldout_rmse, improvement, _new_parameters(base.model, fit.model)
            )
        )
        say(
            f"  + {effect.name:<22} held-out RMSE {heldout_rmse:6.2f} ({100 * improvement:+.1f}%)"
            + ("" if fit.converged else f" [{fit.status}]")
        )
    results.sort(key=lambda c: c.heldout_rmse)
    if results and results[0].heldout_rmse < base_rmse:
        # Every estimate of the noise is biased up by what the model misses: the best
        # model gives the tightest one.
        noise = min(noise, noise_floor_levels(capture, heldout, results[0].fit.model))
    verdict = "none"
    if (
        results
        and base_rmse > ABOVE_NOISE * noise
        and results[0].improvement >= MATERIAL_IMPROVEMENT
    ):
        verdict = results[0].effect
    return Diagnosis(
        base, base_rmse, noise, results, verdict, calib, heldout, time.perf_counter() - started
    )
