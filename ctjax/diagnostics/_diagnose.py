"""Where the model fails, and which physical effect is missing (`ctjax diagnose`).

The base model is the paper's (Lambertian + Beckmann specular with constant F, the light at
the camera centre, constant intensity). It is fitted on the calibration frames and judged on
held-out frames; then every candidate effect is added in turn, refitted, and ranked by its
held-out RMSE. The noise floor is estimated from the data itself (differences of
neighbouring residuals, where any smooth model error cancels), so the user knows when the
model explains everything there is to explain.
"""

import dataclasses
import functools
import threading
import time

import numpy as np

from .._errors import CtjaxError, ParameterError
from .._result import Estimate
from .._threads import checked_workers, in_order
from ..estimation import ALBEDO_CHOICES, default_albedo, why_no_albedo_map
from ..fitting import (
    MAP_LM_DTYPE,
    ShadingModel,
    fit_model,
    fit_model_map,
    free_parameters,
    paper_model,
    pixel_columns,
    pixel_predict,
    roughness_variants,
)
from ..fitting._parameters import per_frame_names
from ..heldout import HeldOut, HeldOutTracks, noise_floor_map_levels, split_for
from ..io import Capture
from ..observations import Observations
from ._candidates import CANDIDATES, AbstractCandidate, candidate
from ._compared import compared
from ._diagnosis import MATERIAL_IMPROVEMENT, Diagnosis

# The fewest calibration samples a diagnosis is fitted on (`max_samples`): the tests' fewest.
# With 2 to 50 the fuzz sweep got "determined" verdicts on base RMSEs of 730 levels, and with
# 100 a candidate's roughness driven to 0.
MIN_SAMPLES = 500

# A noise floor above this (8-bit levels) is no video's: the frames do not agree.
NOISY_FLOOR_LEVELS = 20.0

# LM runs from this many of a model's starts (with their roughness variants), those of
# lowest projected cost: each LM run is most of a candidate's time.
REFINE = 2


class Prepared:
    """A capture made ready for diagnoses: its observations (decoded once), the candidates'
    context and the held-out split of each albedo choice (`split_for`), each built when
    first needed and then shared by every diagnosis of these settings: the uniform and the
    map diagnosis of a first step, the `albedo_texture` candidate's tracks (the map's
    split), a loop's steps. `diagnose` takes one in place of a capture."""

    def __init__(
        self,
        capture: "Capture | Observations",
        calibration: int | None = None,
        max_samples: int = 12_000,
        heldout_samples: int = 40_000,
        seed: int = 0,
    ):
        self.capture = capture
        self.settings = (calibration, max_samples, heldout_samples, seed)
        self._splits = {}
        self._lock = threading.Lock()  # candidates on several threads share the splits

    @classmethod
    def of(cls, capture, calibration, max_samples, heldout_samples, seed) -> "Prepared":
        """`capture` itself when it is prepared with these settings; else a new one (on the
        same observations)."""
        settings = (calibration, max_samples, heldout_samples, seed)
        if isinstance(capture, Prepared):
            if capture.settings == settings:
                return capture
            capture = capture.observations
        return cls(capture, *settings)

    @functools.cached_property
    def observations(self) -> Observations:
        obs = Observations.of(self.capture)
        if not obs.capture.has_geometry or any(f.depth is None for f in obs.frames):
            raise CtjaxError(
                f"{obs.root}: diagnose needs depth for every frame (depth/NAME.npy;"
                " `ctjax reconstruct CAPTURE` estimates it from the images)"
            )
        return obs

    @functools.cached_property
    def _context(self) -> dict:
        obs = self.observations
        return {**obs.candidate_context(), "albedo_map_possible": default_albedo(obs) == "map"}

    def context(self, albedo: str) -> dict:
        """What a candidate needs to know of the capture (`AbstractCandidate.__call__`)."""
        return {**self._context, "albedo": albedo}

    def split(self, albedo: str) -> "HeldOut | HeldOutTracks":
        """The held-out split for `albedo` (`split_for`), built once; its `CtjaxError` (too
        few calibration frames for a map) raised again at every call."""
        with self._lock:
            self._build_split(albedo)
        split = self._splits[albedo]
        if isinstance(split, CtjaxError):
            raise CtjaxError(str(split))
        return split

    def _build_split(self, albedo: str) -> None:
        if albedo not in self._splits:
            calibration, max_samples, heldout_samples, seed = self.settings
            try:
                self._splits[albedo] = split_for(
                    self.observations,
                    calibration,
                    albedo=albedo,
                    max_samples=max_samples,
                    heldout_samples=heldout_samples,
                    seed=seed,
                )
            except CtjaxError as error:
                self._splits[albedo] = error


def _new_parameters(base: ShadingModel, fitted: ShadingModel) -> dict:
    """Values of the parameters the candidate introduced (names not in the base model)."""
    known = {p.name for p in free_parameters(base)}
    out = {}
    for p in free_parameters(fitted):
        if p.name not in known:
            value = np.asarray(p.get(fitted))
            out[p.name] = value.tolist() if value.ndim else float(value)
    return out


def _fit(starts, heldout, max_steps, freeze=()) -> Estimate:
    """LM from the `REFINE` best of `starts` and their roughness variants: with one albedo per
    surface point on tracks (`HeldOutTracks`), or one albedo on pixels (`HeldOut`);
    `freeze` names parameters held at their start."""
    starts = [variant for start in starts for variant in roughness_variants(start)]
    if isinstance(heldout, HeldOutTracks):
        return fit_model_map(
            starts,
            heldout.train,
            freeze=freeze,
            max_steps=max_steps,
            refine=REFINE,
            standard_errors=False,
            dtype=MAP_LM_DTYPE,
        )
    return fit_model(
        starts,
        heldout.train,
        pixel_predict,
        columns=pixel_columns,
        freeze=freeze,
        max_steps=max_steps,
        refine=REFINE,
    )


def _base_per_frame(starts, base) -> tuple[str, ...]:
    """The per-frame parameters (`PER_FRAME`) of a candidate's starts that the base model
    already had: a candidate keeps them at the base's values (a frame's exposure is a
    nuisance each candidate would refit alike, at the cost of a Jacobian column per frame;
    the held-out frames' are fitted when judged, `HeldOutTracks.with_heldout_frames`)."""
    if not per_frame_names(base.model):
        return ()
    return tuple(per_frame_names(starts[0]))


def _training_size(heldout) -> str:
    """How many surface points (albedo map) or pixels (uniform) the models are fitted on."""
    if isinstance(heldout, HeldOutTracks):
        return f"{int(np.sum(np.any(np.asarray(heldout.train.weight) > 0, axis=0)))} points"
    return f"{len(heldout.train.values)} pixels"


def _per_frame_on_calibration(base: Estimate, heldout, max_steps) -> Estimate:
    """`base` with its per-frame parameters refitted on the calibration frames, all else
    held, and that fit's cost: the base as its candidates see it.

    Judging a model fits its per-frame parameters (a frame's exposure) on the held-out
    samples (`judge`), and the held-out tracks see the calibration frames too: the judged
    model's calibration frames then differ from those its cost was computed with.
    Candidates start from the base, keep its per-frame values (`_base_per_frame`) and are
    reported as the base when they end above its cost: with the judged values and the
    calibration fit's cost every one did (the shared sinus after `frame_exposure`: all 14
    candidates at the base's held-out RMSE to 1e-9, the loop stopped with `none`). The
    held-out frames' values stay as judged (the calibration samples do not see them). On
    pixels (`HeldOut`) the held-out samples are the held-out frames' alone: nothing to do."""
    if not isinstance(heldout, HeldOutTracks) or not per_frame_names(base.model):
        return base
    held = [p.name for p in free_parameters(base.model) if not p.per_frame]
    refit = fit_model_map(
        base.model,
        heldout.train,
        freeze=held,
        max_steps=max_steps,
        standard_errors=False,
        dtype=MAP_LM_DTYPE,
    )
    if not np.isfinite(refit.cost):
        return base
    return dataclasses.replace(base, model=refit.model, cost=refit.cost)


def _base_model(heldout, add, candidates, context, max_steps, say, fitted=None) -> Estimate:
    """The paper's model with every effect of `add` added in turn, each fitted from the
    previous one's solution, judged on the held-out frames (with the noise floor). `fitted`:
    that model already fitted and judged without the floor (`next_base`), reused."""
    if fitted is not None:
        grown = " + ".join(["paper", *map(_name, add)])
        say(
            f"the base model ({context['albedo']} albedo, {grown}): the previous step's "
            "candidate, as fitted there"
        )
        model = fitted.model  # its per-frame parameters already fitted on the held-out frames
        floor = fitted.details.get("noise_floor")  # computed when it was the best candidate
        reused = dataclasses.replace(
            fitted,
            noise_floor=heldout.noise_floor(model) if floor is None else floor,
            details={"albedo": context["albedo"]},
            warnings=list(fitted.warnings),
        )
        return _per_frame_on_calibration(reused, heldout, max_steps)
    say(
        f"fitting the base model ({context['albedo']} albedo) on frames {heldout.calibration} "
        f"({_training_size(heldout)})"
    )
    base_starts = [paper_model(1.0, 0.3, s) for s in (0.08, 0.2, 0.45)]
    base = _fit(base_starts, heldout, max_steps)
    for extra in add:
        effect = candidate(extra, (*candidates, *CANDIDATES)) if isinstance(extra, str) else extra
        starts = effect(base.model, context)
        if not starts:
            raise CtjaxError(f"effect {effect.name} does not apply to this model")
        say(f"adding {effect.name} to the base model")
        base = _fit(starts, heldout, max_steps)
    return _per_frame_on_calibration(heldout.judge(base), heldout, max_steps)


def _name(effect) -> str:
    return effect if isinstance(effect, str) else effect.name


def _candidate_fit(effect, starts, base, heldout, prepared, max_steps) -> Estimate | None:
    """The candidate's fit, judged on held-out frames; None when it failed. A candidate
    fitted with the albedo map (`albedo = "map"`) gets the map's split (the base has one
    albedo); one that ends worse than the base it contains on the same calibration data
    is reported as the base (its starts include the base's solution: a worse end is the
    solver's, not the effect's)."""
    freeze = _base_per_frame(starts, base)
    if getattr(effect, "albedo", None) == "map":
        try:
            tracks = prepared.split("map")
        except CtjaxError:  # e.g. too few calibration frames for a map
            return None
        fit = _fit(starts, tracks, max_steps, freeze)
        if not np.isfinite(fit.cost):
            return None
        steps = fit.details.get("steps")
        fit = tracks.judge(fit, noise_floor=False)
        fit.details = {"frozen": list(freeze), "steps": steps, "judged_on": "map"}
        return fit
    try:
        fit = _fit(starts, heldout, max_steps, freeze)
    except ParameterError:  # e.g. an image effect the albedo map cannot undo
        return None
    if not np.isfinite(fit.cost):
        return None
    if fit.cost > base.cost:
        fit = dataclasses.replace(
            fit,
            model=base.model,
            cost=base.cost,
            warnings=[*fit.warnings, NO_BETTER],
        )
    steps = fit.details.get("steps")
    fit = heldout.judge(fit, noise_floor=False)
    fit.details = {"frozen": list(freeze), "steps": steps}
    return fit


# The warning of a candidate reported as its base (`_candidate_fit`).
NO_BETTER = "no better than the base"


def _candidates(
    base, add, candidates, context, heldout, prepared, max_steps, say, workers=1
) -> list:
    """Every candidate effect not in `add`, fitted on top of `base` and judged, on `workers`
    threads (JAX releases the GIL while it compiles and runs a program: one candidate
    compiles while another runs). Reported in the candidates' order; each one's `seconds`
    is its own wall time, shared with the others' when `workers` > 1."""
    added = {_name(e) for e in add}

    def one(effect):
        started = time.perf_counter()
        starts = effect(base.model, context)
        if not starts:
            return None
        fit = _candidate_fit(effect, starts, base, heldout, prepared, max_steps)
        if fit is None:
            return None
        seconds = time.perf_counter() - started
        improvement = (base.heldout_rmse - fit.heldout_rmse) / base.heldout_rmse
        judged = fit.details
        fit.details = {
            "effect": effect.name,
            "improvement": improvement,
            "params": _new_parameters(base.model, fit.model),
            "frozen": fit.details["frozen"],
            "steps": fit.details["steps"],
            "seconds": round(seconds, 2),
        }
        if "judged_on" in judged:  # another split's samples than the base's (`compared`)
            fit.details["judged_on"] = judged["judged_on"]
        return fit

    todo = [effect for effect in candidates if effect.name not in added]
    results = []
    for effect, fit in zip(todo, in_order(one, todo, workers), strict=True):
        if fit is None:
            continue
        results.append(fit)
        say(
            f"  + {effect.name:<22} held-out RMSE {fit.heldout_rmse:6.2f} "
            f"({100 * fit.details['improvement']:+.1f}%) {fit.details['seconds']:4.0f} s"
            + ("" if fit.converged else f" [{fit.status.name}]")
        )
    return results


def next_base(diagnosis: Diagnosis) -> Estimate | None:
    """The base model of the next step of a loop (this base plus the verdict), when this
    diagnosis has already fitted it: the verdict's candidate, fitted on the same calibration
    data from the same starts as the base model with the verdict in `add` would be (the
    effects are added in the same order, each from the previous solution), and judged on
    the same held-out data (`diagnose` adds the noise floor). None (fit it again) when the
    candidate is not that fit: the verdict is "none" or `albedo_texture` (the map's base is
    fitted from the paper's starts), the candidate ended no better than its base (it is
    reported as the base), or it held per-frame parameters at the base's values (the base
    model refits them with the rest)."""
    if diagnosis.verdict in ("none", "albedo_texture"):
        return None
    for c in diagnosis.candidates:
        if c.details["effect"] == diagnosis.verdict:
            if NO_BETTER in c.warnings or c.details.get("frozen"):
                return None
            return c
    return None


def diagnose(
    capture: "Capture | Observations | Prepared",
    *,
    calibration: int | None = None,
    add: tuple[str | AbstractCandidate, ...] = (),
    candidates: tuple[AbstractCandidate, ...] = CANDIDATES,
    albedo: str | None = None,
    max_samples: int = 12_000,
    heldout_samples: int = 40_000,
    max_steps: int = 80,
    seed: int = 0,
    progress=None,
    base: Estimate | None = None,
    workers: int | None = None,
) -> Diagnosis:
    """Fit the paper's model (plus `add`) and rank every candidate effect by held-out RMSE.

    `albedo`: `"map"` (one albedo per surface point, eliminated in closed form, for the base
    and every candidate) or `"uniform"` (the paper's one albedo; the `albedo_texture`
    candidate then tries the map). By default the paper's model first, and the map when
    `albedo_texture` is its verdict (the texture is what it misses most): textured tissue is
    diagnosed with the map, untextured with the paper's model (and its faster fits). With the
    map, `max_samples` bounds the calibration frames' tracked points and half of
    `heldout_samples` the held-out frames' (see `HeldOutTracks`).

    `capture` may be `Prepared` (its observations and splits are then reused when its
    settings are these). `base`: the base model (the paper's plus `add`, with `albedo`)
    already fitted and judged on this split, as `next_base` gives it; fitted here when None.
    `workers`: candidates fitted at once, on threads (default: the cores, at most 4,
    `ctjax._threads.default_workers`); the results do not depend on it.
    """
    started = time.perf_counter()
    say = progress or (lambda message: None)
    if albedo is not None and albedo not in ALBEDO_CHOICES:
        raise CtjaxError(f"albedo must be one of {ALBEDO_CHOICES}, got {albedo!r}")
    if base is not None and albedo is None:
        raise ParameterError("a fitted base model needs its albedo choice (albedo=...)")
    workers = checked_workers(workers)
    for extra in add:  # an unknown name before any work, not after the base model's fit
        if isinstance(extra, str):
            candidate(extra, (*candidates, *CANDIDATES))
    if not max_samples >= MIN_SAMPLES:
        raise ParameterError(
            f"max_samples (--max-samples) must be at least {MIN_SAMPLES}, got {max_samples}: "
            "fewer calibration samples cannot rank the candidates (2 to 50 gave verdicts on "
            "RMSEs of hundreds of levels)"
        )
    prepared = Prepared.of(capture, calibration, max_samples, heldout_samples, seed)
    capture = prepared.observations
    options = dict(
        calibration=calibration,
        add=add,
        candidates=candidates,
        max_samples=max_samples,
        heldout_samples=heldout_samples,
        max_steps=max_steps,
        seed=seed,
        progress=progress,
        workers=workers,
    )
    if albedo is None:
        # The paper's model first; the map when texture is what it misses most.
        unmapped = why_no_albedo_map(prepared.observations)
        uniform = diagnose(prepared, albedo="uniform", **options)
        if unmapped is not None:
            uniform.warnings.insert(0, unmapped)
        if uniform.verdict != "albedo_texture":
            return uniform
        say("the albedo texture is what the paper's model misses most: diagnosing with the map")
        mapped = diagnose(prepared, albedo="map", **options)
        return dataclasses.replace(mapped, seconds=time.perf_counter() - started)
    context = prepared.context(albedo)
    heldout = prepared.split(albedo)
    base = _base_model(heldout, add, candidates, context, max_steps, say, base)
    base.details["albedo"] = albedo
    noise = base.noise_floor
    say(f"base model: held-out RMSE {base.heldout_rmse:.2f} levels, noise floor {noise:.2f}")

    results = _candidates(
        base, add, candidates, context, heldout, prepared, max_steps, say, workers
    )
    results.sort(key=lambda c: c.heldout_rmse)
    if results and results[0].heldout_rmse < base.heldout_rmse:
        # Every estimate of the noise is biased up by what the model misses: the best
        # model gives the tightest one (the texture, under the map's floor).
        best = results[0]
        if best.details["effect"] == "albedo_texture":
            noise = min(noise, noise_floor_map_levels(capture, heldout.heldout, best.model))
        else:
            # Kept: the floor of the next step's base when this is the verdict (`next_base`).
            best.details["noise_floor"] = heldout.noise_floor(best.model)
            noise = min(noise, best.details["noise_floor"])
    verdict = "none"
    if results and results[0].details["improvement"] >= MATERIAL_IMPROVEMENT:
        verdict = results[0].details["effect"]
    leading, close = compared(heldout, base, results)
    warnings = []
    if noise > NOISY_FLOOR_LEVELS:
        warnings.append(
            f"the held-out frames' noise floor is {noise:.1f} levels (1.7-2.6 on the shared "
            "real videos): their pixels do not follow the surface from view to view (noise, "
            "frames of another scene, or a shape not theirs); no verdict means much on them"
        )
    seconds = time.perf_counter() - started
    return Diagnosis(base, noise, results, verdict, seconds, heldout, warnings, leading, close)
