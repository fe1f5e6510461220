"""The paper's per-pixel light field (section 5, eqs. 7-8).

Per pixel of S-bar, the light's direction L is fitted by Levenberg-Marquardt (on autodiff
Jacobians of the renderer's physics, `BRDF.radiance`), vmapped over pixels and jitted, with
the BRDF (rho~, F~, sigma) estimated first. The solver is passed in: optimistix's LM (the
reference) or `ClosedFormLM`, the same method written out for the 2 unknowns (~10x faster on
CPU for the same directions). The solve starts from
the boundary condition on the specular set S and propagates outwards, band after band of
pixels, each starting from its already-solved neighbours; a cubic B-spline is then fitted
over the image, and every pixel is solved once more against it, giving a smooth field
(`LightField`) that the renderer evaluates at any pixel.

The parts: `_field_problem.py` (one pixel's problem, eq. 8, and the vmapped solve),
`ctjax.solvers.ClosedFormLM` (the 2x2 LM), `_field_propagation.py` (observations, bands from S),
`_spline.py` (the B-spline); this module puts them together.

Conventions and choices, all measured on synthetic captures (see `benchmarks/light_lm.py`):

- **Boundary value on S.** The paper writes L = (0, 0, 1) on S: the optical axis, in a frame
  whose z points back towards the camera. With ctjax's camera frame (z forward, directions
  pointing away from the surface), the paper's assumption "the light is co-located with the
  camera on S" is L = V, the pixel's view direction (what `ColocatedLight` returns), which
  differs from the optical axis by the pixel's ray angle (up to ~30 degrees in the corners):
  L = V is the boundary value used here.
- **Angles.** `theta`, `phi` are eq. (7)'s tilt and slant in the paper's frame, which is
  ctjax's camera frame turned by 180 degrees about x (x right, y up, z towards the viewer):
  `L = (sin phi cos theta, -sin phi sin theta, -cos phi)` in ctjax's frame. They are
  reported, but LM works in tangent-plane coordinates around each pixel's start direction:
  eq. (7) is singular at phi = 0, which is exactly the boundary value near the image centre
  (the Jacobian in theta vanishes there). The model is the same, a unit direction per pixel.
- **Well-posedness.** One RGB value gives essentially one equation for two angles (the
  diffuse term sees only N.L; the specular term matters near highlights only), so a valley
  of equally good directions remains and noise picks a point in it. Two additions, inside
  the paper's model: (1) every calibration frame at once: the light is rigid with the
  camera, so a pixel's L is shared by the frames, each of which adds a shading equation with
  another normal; (2) a smoothness prior: extra residuals `(L - L_prior) / prior_deg`
  (a departure of `prior_deg` degrees costs as much as one 8-bit level), towards the mean
  of the solved neighbours while propagating, and towards the spline afterwards.
- **Spline.** A least-squares cubic B-spline on a coarse uniform knot grid, with a small
  second-difference penalty that fills holes (pixels without data), fitted to the three
  components of L - V (not to theta and phi, which wrap around and are singular at phi = 0,
  as `LightField` does for interpolation); normalised after evaluation.
"""

import dataclasses
import math
import time

import jax
import numpy as np
import optimistix as optx

from .._determined import flag_model
from .._errors import CtjaxError
from .._model import ShadingModel
from .._result import Estimate
from .._status import Status
from ..estimation import ALBEDO_CHOICES, default_albedo, why_no_albedo_map
from ..estimation._dense_maps import albedo_maps
from ..fitting import (
    MAP_LM_DTYPE,
    TrackSamples,
    fit_model,
    fit_model_map,
    free_parameters,
    lobe_gain_where_it_shows,
    paper_model,
    pixel_columns,
    pixel_predict,
    roughness_variants,
    strongly_typed,
)
from ..fitting._map_least_squares import diffuse_lobe
from ..heldout import (
    SIMPLEST_WITHIN,
    HeldOut,
    HeldOutTracks,
    simplest_within,
    split_for,
    split_frames,
)
from ..io import Capture
from ..lights import AbstractFalloff, ColocatedLight, InverseSquare, LightField
from ..lobes import BRDF
from ..observations import Observations
from ..solvers import ClosedFormLM
from ..specular import MaskOptions
from ._field_problem import paper_angles, solve_pixels
from ._field_propagation import field_observations, propagate, solve_batches
from ._lobe_halves import sample_lobe_halves
from ._spline import spline_field

# The reference per-pixel solver (optimistix's LM) and its step limit.
FIELD_SOLVER = optx.LevenbergMarquardt(rtol=1e-4, atol=1e-6)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cosine = np.clip(np.sum(a * b, axis=-1), -1, 1)
    return np.degrees(np.arccos(cosine))


def fit_field_brdf(model: ShadingModel, samples, *, max_steps: int, freeze=()) -> Estimate:
    """The BRDF (rho~, F~, sigma) under `model`'s light on `samples`: pixel samples (one
    albedo) or `TrackSamples` (an albedo per surface point, eliminated in closed form; its
    LM in `MAP_LM_DTYPE`, as the other commands' map fits). `freeze`: parameters held."""
    if isinstance(samples, TrackSamples):
        return fit_model_map(
            roughness_variants(model),
            samples,
            max_steps=max_steps,
            refine=3,
            standard_errors=False,
            dtype=MAP_LM_DTYPE,
            freeze=freeze,
        )
    return fit_model(
        roughness_variants(model),
        samples,
        pixel_predict,
        columns=pixel_columns,
        max_steps=max_steps,
        refine=3,
        freeze=freeze,
    )


def _first_brdf(heldout: HeldOut, falloff, brdf: BRDF | None) -> Estimate:
    """Step 1: the paper's model (L = V) with `falloff`, or (None) without and with an
    inverse-square falloff, the simpler unless the other is 1% better on held-out frames (a
    unit-irradiance field would turn an unmodelled falloff into direction errors: measured
    ~30 degrees); or `brdf` as given."""
    if falloff is None:
        falloff = [(), (InverseSquare(heldout.capture.median_depth_mm()),)]
    else:
        falloff = [tuple(falloff)]
    if brdf is not None:
        choice = falloff[0] if len(falloff) == 1 else ()
        return Estimate(ShadingModel(brdf, ColocatedLight(falloff=choice)), status=Status.given)
    fits = [
        fit_field_brdf(
            strongly_typed(ShadingModel(paper_model().brdf, ColocatedLight(falloff=choice))),
            heldout.train,
            max_steps=100,
        )
        for choice in falloff
    ]
    errors = [heldout.heldout_rmse(f.model) for f in fits]
    return fits[simplest_within(falloff, errors, observations=heldout.capture)]


def _field_round(obs, boundary, todo, brdf, solve, knot_px, field):
    """Steps 2-3 once: the per-pixel directions (propagated from S when `field` is None,
    else started from it), their spline, every pixel solved again towards the spline, and
    the spline of that: (field, per-pixel directions, per-pixel solution). `solve` is
    `solve(problems, brdf)`."""
    view = obs.view.astype(float)
    if field is None:
        directions = propagate(obs, boundary, todo, brdf, solve)
    else:
        directions = field.copy()
    weight = todo.astype(float)
    spline = spline_field(np.nan_to_num(directions), view, weight, knot_px)
    index = np.flatnonzero(todo)
    start = np.where(np.isfinite(directions), directions, spline).reshape(-1, 3)
    start = np.where(np.isfinite(start), start, view.reshape(-1, 3))
    solution = solve_batches(obs, index, start, spline.reshape(-1, 3), brdf, solve)
    pixel_directions = np.full(view.shape, np.nan)
    pixel_directions.reshape(-1, 3)[index] = solution["direction"]
    field = spline_field(np.nan_to_num(pixel_directions), view, weight, knot_px)
    return field, pixel_directions, solution


def _boundary_and_todo(obs: Observations, calib):
    capture, sets = obs, obs.sets
    boundary = np.any([sets[i].specular for i in calib], axis=0)
    if not boundary.any():
        raise CtjaxError(
            f"{capture.root}: no specular pixels (S is empty) in the calibration frames "
            f"{calib}: the light field's boundary condition L = V on S needs a highlight"
        )
    observed = np.zeros(boundary.shape, bool)
    for i in calib:
        observed |= obs.usable[i] & ~sets[i].specular & ~sets[i].saturated
    todo = observed & ~boundary
    if not todo.any():
        raise CtjaxError(f"{capture.root}: no pixel of S-bar in the calibration frames {calib}")
    return boundary, todo


def _result(heldout, final, field, pixel_directions, todo, status, boundary, view) -> Estimate:
    """The field as an `Estimate`: errors, counts, angles and the per-pixel maps."""
    fit = Estimate(
        final,
        heldout.rmse(final),
        noise_floor=heldout.noise_floor(final),
        frames=heldout.frames,
    )
    colocated = ShadingModel(final.brdf, ColocatedLight(falloff=final.light.falloff))
    spline_vs_pixel = _angle_deg(field[todo], pixel_directions[todo])
    change = _angle_deg(field, view)
    theta, phi = paper_angles(field)
    fit.status = Status.worst(status)
    fit.details = {
        "model": "field",
        "light": "field",
        "note": "per-pixel light directions (eq. 7-8), camera frame; L = V on S",
        "rgb_rmse_heldout_colocated": heldout.heldout_rmse(colocated),
        "solver_status": Status.counts(status[todo]),
        "solved_pixels": int(todo.sum()),
        "boundary_pixels": int(boundary.sum()),
        "median_angle_spline_to_pixel_deg": float(np.median(spline_vs_pixel))
        if spline_vs_pixel.size
        else None,
        "median_angle_from_view_deg": float(np.median(change)),
        "max_angle_from_view_deg": float(np.max(change)),
    }
    fit.arrays = {
        "directions": field.astype(np.float32),
        "theta": theta.astype(np.float32),
        "phi": phi.astype(np.float32),
        "pixel_directions": pixel_directions.astype(np.float32),
        "solved": todo,
        "status": status.astype(np.int8),
        "boundary": boundary,
        "view": view.astype(np.float32),
    }
    # The field's BRDF: a lobe the data show (where it shows, against the diffuse term
    # alone under the same field), a roughness in range, the same on the even and on the
    # odd calibration frames.
    gain = _lobe_gain(fit, heldout.train)
    fit = flag_model(fit, lobe_gain=gain)
    if Status(fit.status) == Status.successful:
        halves = sample_lobe_halves(
            final,
            heldout.train,
            lambda starts, samples, freeze: fit_field_brdf(
                starts[0], samples, max_steps=50, freeze=freeze
            ),
        )
        if halves:
            fit.details["sigma_halves"] = {
                n: dict(zip(("even_frames", "odd_frames"), v, strict=True))
                for n, v in halves.items()
            }
            fit = flag_model(fit, lobe_gain=gain, halves=halves)
    return fit


def _lobe_gain(fit: Estimate, samples) -> float | None:
    """What the lobes bring under the field where they show (at least one 8-bit level): 1 -
    RMSE / RMSE of the diffuse term alone refitted under the same field (held) on the
    calibration tracks, each point's albedo eliminated (`lobe_gain_where_it_shows`, as the
    near light's); also in `fit.details`. None with one albedo (pixel samples) or where that
    refit does not give a finite cost."""
    if not isinstance(samples, TrackSamples):
        return None
    model = fit.model
    lambertian = ShadingModel(BRDF(model.brdf.lobes[diffuse_lobe(model)]), model.light)
    held = [p.name for p in free_parameters(lambertian) if not p.name.startswith("brdf")]
    plain = fit_model_map(
        lambertian, samples, freeze=held, standard_errors=False, dtype=MAP_LM_DTYPE
    )
    if not np.isfinite(plain.cost) or plain.cost <= 0:
        return None
    gain, shows = lobe_gain_where_it_shows(model, plain.model, samples)
    fit.details["lobe_gain"], fit.details["lobe_shows_observations"] = gain, shows
    return gain


def _warn_unless_better(result: Estimate, albedo: str) -> None:
    """A warning unless the field beats the light at the lens (L = V) on held-out frames."""
    colocated = result.details["rgb_rmse_heldout_colocated"]
    if result.heldout_rmse > (1 - SIMPLEST_WITHIN) * colocated:
        result.warnings.append(
            f"the field does not explain the held-out frames better than the light at the "
            f"lens, L = V ({result.heldout_rmse:.3f} vs {colocated:.3f} levels): these data "
            "show no departure from L = V that the field captures; the simpler model will do"
            + (
                " (with an albedo per surface point, most of a smooth field's shading is "
                "absorbed by the albedos: a light offset from the lens is better found by "
                "the near-light model, calibrate-light --model near)"
                if albedo == "map"
                else ""
            )
        )


def calibrate_light_field(
    capture: "Capture | Observations",
    calibration: int | None = None,
    *,
    solver: ClosedFormLM | optx.AbstractLeastSquaresSolver = FIELD_SOLVER,
    max_steps: int = 24,
    prior_deg: float = 6.0,
    knot_px: float | None = None,
    brdf_rounds: int = 3,
    brdf: BRDF | None = None,
    falloff: tuple[AbstractFalloff, ...] | None = None,
    albedo: str | None = None,
    masks: MaskOptions | None = None,
    max_samples: int = 12_000,
    heldout_samples: int = 40_000,
    seed: int = 0,
    progress=None,
) -> Estimate:
    """The paper's per-pixel light field from the calibration frames (default: the first
    60%), judged on the held-out frames.

    1. BRDF: the paper's model with L = V fitted on the calibration frames (or `brdf` as
       given). Without `falloff`, it is also fitted with an inverse-square falloff from
       the lens, kept only if 1% better on the held-out frames; `falloff` (e.g. `()` or
       `(InverseSquare(70.0),)`) forces the choice.
    2. Per pixel of S-bar (usable, not specular, in at least one calibration frame), L on
       eq. (8) over all calibration frames by `solver` (optimistix's LM with at most
       `max_steps` steps, the reference; or `ClosedFormLM(iterations)`, several times faster
       and as accurate on synthetic captures, `benchmarks/light_lm.py`), propagated from
       L = V on S outwards in bands, with a prior towards the solved neighbours
       (`prior_deg`, see the module).
    3. A cubic B-spline (knots every `knot_px`, default ~1/8 of the image) of the solution,
       then every pixel solved again with the prior towards the spline, and the spline
       refitted: the field.
    4. With `brdf_rounds` > 1, the BRDF is refitted under the field and steps 2-3 repeated
       from the field.

    `albedo`: `"map"` (one albedo per surface point: textured tissue; the default when
    every frame has depth and a pose) or `"uniform"` (one albedo, the paper's). With the
    map, step 1 fits surface points tracked across the calibration frames with every
    point's albedo eliminated in closed form (`fit_model_map`), and before each round of
    steps 2-3 every calibration pixel's albedo is estimated from the calibration frames
    that see its surface point under the current light (`albedo_maps`): the per-pixel
    problem then has the albedo of the point each frame shows there, and only the light's
    direction is left to explain the shading. Without it, texture is read as light
    directions (measured: ~45 degrees from V on a textured capture lit from the lens).

    Returns an `Estimate` of the `ShadingModel` with its `LightField`: `status` is the
    worst per-pixel status, `arrays` hold the smooth field `directions` (H, W, 3), eq. (7)'s
    `theta`, `phi`, the per-pixel solution `pixel_directions` (NaN where not solved),
    `solved`, the per-pixel `status` (`Status` codes, -1 where not solved), the
    `boundary` S and the `view` directions; `details` the counts and angles. Raises
    `CtjaxError` without depth and normals, without specular pixels (the boundary S is
    empty) or without pixels in S-bar.
    """
    say = progress or (lambda message: None)
    started = time.perf_counter()
    capture = Observations.of(capture, masks)
    if any(f.depth is None or f.normals is None for f in capture.frames):
        raise CtjaxError(
            f"{capture.root}: the light field needs depth and normals for every frame"
            " (`ctjax reconstruct CAPTURE` estimates them from the images)"
        )
    unmapped = why_no_albedo_map(capture) if albedo is None else None
    albedo = default_albedo(capture) if albedo is None else albedo
    if albedo not in ALBEDO_CHOICES:
        raise CtjaxError(f"albedo must be one of {ALBEDO_CHOICES}, got {albedo!r}")
    calib, _ = split_frames(len(capture), calibration, source=capture.root)
    boundary, todo = _boundary_and_todo(capture, calib)
    heldout = split_for(
        capture,
        calibration,
        albedo=albedo,
        max_samples=max_samples,
        heldout_samples=heldout_samples,
        seed=seed,
    )
    knot_px = max(8.0, max(boundary.shape) / 8) if knot_px is None else knot_px
    prior_scale = 1 / math.radians(prior_deg)
    tick = time.perf_counter()
    say(f"BRDF: the paper's model (L = V) on frames {heldout.calibration}")
    fit = _first_brdf(heldout, falloff, brdf)
    per_point = diffuse_lobe(fit.model) if albedo == "map" else None
    timings = {"brdf": time.perf_counter() - tick}

    def solve(problems, brdf):
        return solve_pixels(problems, brdf, prior_scale, solver, max_steps, per_point)

    rounds = _Rounds(heldout, boundary, todo, solve, knot_px, per_point, timings, say)
    final, field, pixel_directions, status, view = rounds.run(fit, brdf_rounds, brdf is None)
    tick = time.perf_counter()
    result = _result(heldout, final, field, pixel_directions, todo, status, boundary, view)
    if not np.isfinite(result.heldout_rmse):
        raise CtjaxError("the light field did not produce finite estimates")
    timings["evaluation"] = time.perf_counter() - tick
    timings["total"] = time.perf_counter() - started
    result.seconds = timings
    result.details["albedo"] = albedo
    result.warnings.extend([unmapped] if unmapped else [])
    _warn_unless_better(result, albedo)
    result.details["settings"] = _settings(solver, max_steps, prior_deg, knot_px, brdf_rounds)
    result.details["settings"]["falloff"] = "+".join(f.name for f in final.light.falloff) or "none"
    return result


@dataclasses.dataclass
class _Rounds:
    """Steps 2-4 of `calibrate_light_field`: rounds of the field, each under the current
    BRDF (and albedo map, with `per_point`), the BRDF refitted between them."""

    heldout: "HeldOut | HeldOutTracks"
    boundary: np.ndarray
    todo: np.ndarray
    solve: object
    knot_px: float
    per_point: int | None
    timings: dict
    say: object

    def observations(self, base, model: ShadingModel):
        """`base` with, given an albedo map, every calibration pixel's albedo under `model`."""
        if self.per_point is None:
            return base
        calib = self.heldout.calibration
        maps, _ = albedo_maps(
            self.heldout.capture.capture,
            model.brdf,
            model.light,
            per_point=self.per_point,
            frames=calib,
            among=calib,
        )
        return base.with_albedo(maps)

    def run(self, fit: Estimate, brdf_rounds: int, refit: bool):
        """(the final model, the field, per-pixel directions, per-pixel status, views)."""
        falloff = fit.model.light.falloff
        dtype = jax.dtypes.canonicalize_dtype(np.float64)
        base = field_observations(self.heldout.capture, self.heldout.calibration, falloff, dtype)
        model, field = fit.model, None
        for round_ in range(brdf_rounds):
            tick = time.perf_counter()
            obs = self.observations(base, model)
            field, pixel_directions, solution = _field_round(
                obs, self.boundary, self.todo, model.brdf, self.solve, self.knot_px, field
            )
            model = ShadingModel(model.brdf, LightField(field, falloff=falloff))
            self.timings[f"field_round_{round_}"] = time.perf_counter() - tick
            if round_ + 1 < brdf_rounds and refit:
                self.say("BRDF: refitted under the light field")
                tick = time.perf_counter()
                model = fit_field_brdf(model, self.heldout.train, max_steps=50).model
                self.timings[f"brdf_round_{round_ + 1}"] = time.perf_counter() - tick
        status = np.full(self.todo.shape, Status.not_solved.value, np.int64)
        status.reshape(-1)[np.flatnonzero(self.todo)] = solution["result"]
        return model, field, pixel_directions, status, base.view


def _settings(solver, max_steps, prior_deg, knot_px, brdf_rounds) -> dict:
    return {
        "prior_deg": prior_deg,
        "knot_px": knot_px,
        "solver": type(solver).__name__,
        "engine": "closed-form" if isinstance(solver, ClosedFormLM) else "optimistix",
        "max_steps": max_steps,
        "brdf_rounds": brdf_rounds,
    }
