"""A physical near-light model of the laparoscope (beyond the paper, section 5's alternative).

The light guide is a point light at an unknown offset from the lens, optionally with
inverse-square and angular (spot) falloff, fitted jointly with the BRDF by Levenberg-Marquardt
over all calibration frames: a handful of global parameters instead of two angles per pixel.
Which falloffs the data show is decided on held-out frames. The light's intensity is folded
into rho_tilde and F_tilde, as the paper does (it is not separable from them).
"""

import math
import time
from collections.abc import Sequence

import numpy as np

from .._determined import flag_model
from .._errors import CtjaxError
from .._json import falloff_json, paper_names
from .._result import Estimate
from .._right_views import with_right_views
from .._status import Status
from .._threads import checked_workers, in_order
from .._units import length_unit_of
from ..effects import image_effects
from ..estimation import ALBEDO_CHOICES, default_albedo, why_no_albedo_map
from ..fitting import (
    LEVENBERG_MARQUARDT,
    MAP_LM_DTYPE,
    ShadingModel,
    fit_model_map,
    free_parameters,
    lobe_gain_where_it_shows,
    map_standard_errors,
    roughness_variants,
)
from ..fitting._map_least_squares import TrackSamples, diffuse_lobe
from ..heldout import (
    SIMPLEST_WITHIN,
    HeldOutTracks,
    median_depth_mm,
    simplest_within,
)
from ..io import Capture
from ..lights import AbstractFalloff, LensPlaneLight
from ..lobes import BRDF, Lambertian
from ..observations import Observations
from ..solvers import Solver
from ..specular import flag_misoriented
from ._frames_brightness import check_frames_brightness
from ._lobe_halves import lobe_halves
from ._near_light_models import (
    OFFSET_AXES,
    at_the_lens,
    falloff_name,
    falloff_sets,
    near_light_starts,
    no_offset,
    offset_axes_of,
    paper_start,
    position_name,
    position_stderr,
    warn_of_misfit,
)
from ._near_light_uniform import near_light_uniform
from ._offset_checks import (
    HIGHLIGHT_MARGIN_PX,
    edge_margin_px,
    far_offset,
    offset_halves,
    offset_normal_tilt,
    placing_views,
    reconstructed,
)


def calibrate_near_light(
    capture: "Capture | Observations",
    *,
    calibration: int | None = None,
    falloff: tuple[AbstractFalloff, ...] | Sequence[tuple[AbstractFalloff, ...]] | None = None,
    solver: Solver = LEVENBERG_MARQUARDT,
    albedo: str | None = None,
    max_samples: int = 12_000,
    heldout_samples: int = 40_000,
    max_steps: int = 100,
    seed: int = 0,
    progress=None,
    right_views: bool = False,
    workers: int | None = None,
    diffuse: type[Lambertian] = Lambertian,
    offset_axes: str = "lens_plane",
    effects: Sequence = (),
) -> Estimate:
    """Fit the near-light model on the calibration frames; report errors on held-out frames.

    `falloff`: the light's falloff factors (e.g. `(InverseSquare(70.0),)`), or several
    such tuples to choose from; by default every subset of `falloff_choices` is fitted and
    the simplest one within 1% of the lowest held-out RMSE is kept. `solver`: the
    least-squares solver (`ctjax.solvers`, or any optimistix one). `albedo`: `"map"` (one
    albedo per surface point, eliminated in closed form: textured tissue; the default when
    every frame has depth and a pose, see `near_light_map`) or `"uniform"` (one albedo, the
    paper's model).

    Returns an `Estimate` of the `ShadingModel` with its `PointLight`; `details` holds the
    chosen `falloff` (by name, with its parameters) and `falloff_selection`, the held-out
    RMSE of every falloff set tried. `progress`: called with a line per step.
    `right_views`: with the map, a stereo capture's right images too (`near_light_map`).
    `workers`: falloff sets fitted at once, on threads (default: the cores, at most 4); the
    results do not depend on it. `diffuse`: the diffuse term (`ctjax.lobes.diffuse_lobes`:
    `Lambertian`, the paper's, or e.g. `OrenNayar`, whose shape is fitted with the rest).
    `offset_axes`: `"lens_plane"` (default) fits the light's offset in the lens plane
    (`LensPlaneLight`: the scope's light leaves the face of its tip), `"free"` along the
    optical axis too (`PointLight`); the JSON's `offset_mm` has x, y, z either way.
    `effects`: image effects fitted with the rest (`ctjax.effects.image_effects`: effects or
    their names, e.g. `("frame_exposure", "vignetting")`: a scope's auto-exposure and its
    optics' falloff); a per-frame one (an exposure per frame) is fitted on the held-out
    frames when they are judged, as `ctjax diagnose` does.
    """
    say = progress or (lambda message: None)
    if offset_axes not in OFFSET_AXES:
        raise CtjaxError(f"offset_axes must be one of {OFFSET_AXES}, got {offset_axes!r}")
    workers = checked_workers(workers)
    capture = Observations.of(capture)
    if any(f.depth is None for f in capture.frames):
        raise CtjaxError(
            f"{capture.root}: the near-light model needs depth for every frame"
            " (`ctjax reconstruct CAPTURE` estimates it from the images)"
        )
    start = paper_start(diffuse)
    effects = image_effects(effects, start, capture.candidate_context()) if effects else ()
    unmapped = why_no_albedo_map(capture) if albedo is None else None
    albedo = default_albedo(capture) if albedo is None else albedo
    if albedo not in ALBEDO_CHOICES:
        raise CtjaxError(f"albedo must be one of {ALBEDO_CHOICES}, got {albedo!r}")
    if albedo == "map":
        fit = near_light_map(
            capture,
            calibration=calibration,
            falloff=falloff,
            solver=solver,
            max_points=max_samples,
            heldout_points=heldout_samples // 2,
            max_steps=max_steps,
            seed=seed,
            progress=progress,
            right_views=right_views,
            workers=workers,
            diffuse=diffuse,
            offset_axes=offset_axes,
            effects=effects,
        )
        return _with_highlight_alignment(fit, capture)
    if right_views:
        raise CtjaxError("the right views are fitted with the albedo map (albedo='map')")
    fit = near_light_uniform(
        capture,
        calibration=calibration,
        falloff=falloff,
        solver=solver,
        max_samples=max_samples,
        heldout_samples=heldout_samples,
        max_steps=max_steps,
        seed=seed,
        say=say,
        workers=workers,
        diffuse=diffuse,
        offset_axes=offset_axes,
        effects=effects,
    )
    fit.warnings.extend([unmapped] if unmapped else [])
    return _with_highlight_alignment(fit, capture)


def _with_highlight_alignment(fit: Estimate, capture: Observations) -> Estimate:
    """`fit` with the highlights' alignment under its light (`flag_misoriented`: H from the
    fitted light's position where it is off the lens)."""
    light = fit.model.light
    position = getattr(light, "position_mm", None)
    position = None if position is None else np.asarray(position, float)
    if position is not None and not np.any(position):
        position = None  # at the lens: H = V
    return flag_misoriented(fit, capture.capture, capture.sets, position)


def _details(result, capture, choices, errors, detected, offset, reported) -> dict:
    """The near-light estimate's details: the model, the falloff chosen and the others'
    held-out errors, the offset (fitted, detected, its standard errors) and their notes."""
    return {
        "model": "near",
        "albedo": "map",
        "intensity_note": "folded into rho_tilde and F_tilde (not separable from them)",
        "falloff": falloff_json(result.model.light),
        "falloff_selection": {
            falloff_name(c): round(e, 4) for c, e in zip(choices, errors, strict=True)
        },
        "offset_detected": detected,
        "offset_mm": np.asarray(result.model.light.position_mm, float).tolist(),
        "offset_axes": offset_axes_of(result.model),
        "offset_fitted_mm": offset.tolist(),
        "offset_stderr_mm": reported,  # None where the data do not determine it
        "length_unit": length_unit_of(capture),
        "rmse_note": "each view of a tracked point predicted with the model fixed and the "
        "point's albedo fitted to its other views (held-out: the held-out frames' views)",
        "parameters_from": "every frame: the model chosen on the held-out frames (falloff, "
        "offset or none) refitted on the surface points of all frames; its held-out and "
        "calibration errors and offset_fitted_mm are those of the fit on the calibration "
        "frames (on a reconstructed shape its light placed, as the refit's, by the views "
        "away from the highlights), the offset's standard errors the refit's (the "
        "calibration fit's when no offset is detected: they set the bound)",
    }


def _take_refit(result, every, tracks, detected: bool, reported, placed=None):
    """The chosen model's parameters from the refit on every frame (when it is finite),
    its RMSE there, and the offset's standard errors: the refit's when an offset is
    detected, else the calibration fit's (`reported`), which set the bound. `placed`: the
    (fit, tracks) that placed the light where `every` held it (`away_from_highlights`): the
    light's standard errors are that fit's, the rest `every`'s."""
    if not np.isfinite(every.cost):
        return reported
    result.model = every.model
    result.rmse["all_frames"] = every.rmse["calibration"]
    if detected:
        result.details["stderr"] = _standard_errors(every.model, tracks, placed)
        reported = position_stderr(result.details["stderr"], every.model, reported)
    return reported


def _standard_errors(model, tracks, placed=None) -> dict:
    """`model`'s standard errors on `tracks`; where `placed` (the fit that placed its
    light, and its tracks) is given, the light's are that fit's with the BRDF held, and the
    rest are `model`'s with the light held."""
    if placed is None:
        return map_standard_errors(model, tracks)
    held = _light_parameters(model)
    # The light's given the BRDF: the placing views may hold no highlight, and a lobe they do
    # not determine would leave every parameter's standard error undetermined (on the shared
    # sinus, its surface's edge set aside: the offset's too, though the views place it).
    others = [p.name for p in free_parameters(placed[0]) if p.name not in held]
    light = map_standard_errors(*placed, freeze=others)
    return map_standard_errors(model, tracks, held) | {
        name: error for name, error in light.items() if name in held
    }


def _placing_train(capture, heldout, max_points, seed, right_views):
    """The calibration frames' tracks (`heldout.train`) with the views that do not place
    the light weighted 0 (`placing_views`: a reconstructed shape's views near the
    highlights), or None where every view places it. On 4 reconstructed synthetic stereo
    captures the calibration frames' offset went from 0.27, 1.59, 0.86 and 2.03 mm off the
    truth with every view to 0.15, 0.04, 0.45 and 0.80 mm; the refit on every frame, which
    already set those views aside, stayed where it was."""
    if not reconstructed(capture):
        return None
    tracks = capture.tracks(frames=heldout.calibration, max_points=max_points, seed=seed)
    right = None
    if right_views:  # as `HeldOutTracks.split` adds them
        tracks, right = with_right_views(capture.capture, tracks, heldout.calibration)
    placing, _ = placing_views(capture, tracks, right)  # the refit below warns
    return None if placing is tracks else TrackSamples.of(placing)


def _light_parameters(model) -> list[str]:
    """The names of `model`'s free parameters of its light (position, falloff)."""
    return [p.name for p in free_parameters(model) if p.name.startswith("light.")]


def near_light_map(
    capture: "Capture | Observations",
    *,
    calibration: int | None = None,
    falloff: tuple[AbstractFalloff, ...] | Sequence[tuple[AbstractFalloff, ...]] | None = None,
    solver: Solver = LEVENBERG_MARQUARDT,
    max_points: int = 12_000,
    heldout_points: int = 20_000,
    max_steps: int = 100,
    refine: int = 2,
    seed: int = 0,
    progress=None,
    right_views: bool = False,
    workers: int | None = None,
    diffuse: type[Lambertian] = Lambertian,
    offset_axes: str = "lens_plane",
    effects: tuple = (),
) -> Estimate:
    """The near-light model on textured tissue: one albedo per surface point.

    Surface points of the calibration frames are followed across them
    (`HeldOutTracks`); for each falloff set, LM runs over the light's offset, the falloff's
    and the BRDF's nonlinear parameters from the `refine` best of several starting offsets
    and roughnesses (by projected cost; 2: at 320x256 x 8 frames, offset (6, -4, 0) mm with
    inverse square, 3 starts and 1 reached the same offset and sigma, 50 s and 23 s against
    37 s), every point's albedo and F_tilde eliminated in closed form (`fit_model_map`).
    The falloff set is chosen on held-out frames (`heldout_map_rmse`), each set as it would
    be reported (the light at the lens unless its offset predicts them 1% better); the
    chosen model is then refitted on the surface points of every frame, so its parameters
    use all the data
    (on the default demo capture sigma +6.2% from the calibration frames, +4.x% from all).
    `right_views`: a stereo capture's right images too, in the fits (calibration frames,
    then every frame; `ctjax._right_views`): V moved with L kept, which a falloff cannot
    mimic. The falloff is still chosen on the held-out frames' left views.

    Whether the data show an offset at all is decided twice: the offset's standard error
    (from the Jacobian of the projected residuals at the solution, in the capture's length
    unit) and the held-out error of the same model with the light at the lens. If the
    light at the lens explains the held-out frames as well (within 1%), or the offset is
    within 2 standard errors of 0, the estimate is the light at the lens, reported with
    `offset_bound_mm` (the fitted offset's norm plus 2 standard errors): the data cannot
    tell an offset below it from none. `workers`: falloff sets fitted at once, on threads.
    `diffuse`, `offset_axes`: as `calibrate_near_light`'s; `effects`: image effects
    (`AbstractImageEffect`s at their start), fitted with the rest.
    """
    started = time.perf_counter()
    workers = checked_workers(workers)
    say = progress or (lambda message: None)
    capture = Observations.of(capture)
    say("tracking surface points across the frames (albedo map)")
    heldout = HeldOutTracks.split(
        capture,
        calibration,
        max_points=max_points,
        heldout_points=heldout_points,
        seed=seed,
        right_views=right_views,
    )
    choices = falloff_sets(capture, falloff)
    # A reconstructed shape's views near the highlights do not place the light: in the
    # calibration frames' fits as in the refit on every frame below.
    placing_train = _placing_train(capture, heldout, max_points, seed, right_views)

    def fit(starts, tracks=heldout.train, **fixed):  # fixed: `freeze` or `hold`
        return fit_model_map(
            starts,
            tracks,
            solver=solver,
            max_steps=max_steps,
            refine=refine,
            standard_errors=False,  # the chosen fit's only, below
            dtype=MAP_LM_DTYPE,
            **fixed,
        )

    say(
        f"fitting the light's offset with {len(choices)} falloff set(s), "
        f"frames {heldout.calibration}"
    )

    def placed_fit(starts, **fixed):
        """`fit` on the calibration frames, the light placed by `placing_train` where
        there is one and the BRDF then refitted on every view with the light held: the fit
        and (its model, the tracks that placed its light) or None."""
        if placing_train is None:
            return fit(starts, **fixed), None
        placed = fit(starts, placing_train, **fixed)
        # Held, not frozen: the same tracks' shapes, so the same compiled program. From
        # several roughnesses: the placing views may hold no highlight, and a lobe lost there
        # (F_tilde 0, where sigma's gradient is 0) would stay lost.
        held = tuple(_light_parameters(placed.model))
        every_view = fit(roughness_variants(placed.model), hold=held)
        return every_view, (placed.model, placing_train)

    def fit_choice(choice):
        """The set with its offset and at the lens (held: the same program), judged as it
        would be reported: at the lens unless its offset is `SIMPLEST_WITHIN` better (SCARED
        61-84: the spot alone 12.49 with its offset, 10.57 at the lens; the pair 11.26)."""
        starts = near_light_starts(choice, capture, diffuse, offset_axes, effects)
        chosen, placed = placed_fit(starts)
        error = heldout.heldout_rmse(chosen.model)
        hold = (position_name(chosen.model),)
        lens = placed_fit(at_the_lens(choice, diffuse, offset_axes, effects), hold=hold)[0]
        lens_error = heldout.heldout_rmse(lens.model)
        offset_better = error < (1 - SIMPLEST_WITHIN) * lens_error
        return chosen, error if offset_better else lens_error, placed, lens, (error, lens_error)

    fits, errors, placements, lens_fits, both = [], [], [], [], {}
    for choice, (chosen, error, placed, lens, pair) in zip(
        choices, in_order(fit_choice, choices, workers), strict=True
    ):
        fits.append(chosen)
        errors.append(error)
        placements.append(placed)
        lens_fits.append(lens)
        both[falloff_name(choice)] = {
            "fitted_offset": round(pair[0], 4),
            "at_the_lens": round(pair[1], 4),
        }
        say(f"  falloff {falloff_name(choice)}: held-out RMSE {error:.3f} levels")
    chosen = simplest_within(choices, errors, observations=heldout.capture)
    offset_fit = heldout.judge(fits[chosen], noise_floor=False)
    if not np.isfinite(offset_fit.heldout_rmse):
        raise CtjaxError("the near-light fit did not produce finite estimates")
    offset = np.asarray(offset_fit.model.light.position_mm, float)
    offset_fit.details["stderr"] = _standard_errors(
        offset_fit.model, heldout.train, placements[chosen]
    )
    reported = position_stderr(offset_fit.details["stderr"], offset_fit.model, [None] * 3)
    stderr = np.asarray([np.inf if e is None else e for e in reported], float)
    say("standard errors, and the same model with the light at the lens")
    lens_fit = heldout.judge(lens_fits[chosen], noise_floor=False)  # fitted with the choice
    fitted = stderr > 0  # the axis in the lens plane is not
    significant = bool(
        np.all(np.isfinite(stderr)) and np.linalg.norm(offset[fitted] / stderr[fitted]) > 2
    )
    better = offset_fit.heldout_rmse < (1 - SIMPLEST_WITHIN) * lens_fit.heldout_rmse
    detected = significant and better
    result = offset_fit if detected else lens_fit
    result.noise_floor = heldout.noise_floor(result.model)
    # The shared sinus: 22.2 levels held out, 8.5x the floor; the cholecystectomy 9.6x.
    warn_of_misfit(result, "what the model lacks: ctjax diagnose")
    say("the chosen model refitted on every frame's surface points")
    tracks = capture.tracks(max_points=max_points, seed=seed)
    if right_views:
        tracks, right = with_right_views(capture.capture, tracks)
    # A reconstructed shape's views near the highlights do not place the light.
    placing = tracks
    if detected:
        placing, warning = placing_views(capture, tracks, right if right_views else None)
        result.warnings.extend([warning] if warning else [])
    # Frozen, not held: other tracks, another program anyway, and fewer Jacobian columns.
    every = fit([result.model], placing, freeze=() if detected else (position_name(result.model),))
    placed = None
    if placing is not tracks and np.isfinite(every.cost):
        say("the BRDF on every view, the light held where the views away from S put it")
        placed = (every.model, placing)
        # From several roughnesses, as in `placed_fit`.
        every = fit(roughness_variants(every.model), tracks, freeze=_light_parameters(every.model))
        result.details["light_placed_by"] = (
            "views farther than "
            f"{HIGHLIGHT_MARGIN_PX} px from their frame's S and clipped pixels and "
            f"{edge_margin_px(capture):g} px from the surface's edge (the shape is "
            "reconstructed: its normals near the highlights are bridged, along the edge "
            "extrapolated, not measured); the BRDF then refitted on every view with the light "
            "held"
        )
    reported = _take_refit(result, every, tracks, detected, reported, placed)
    result.details |= _details(result, capture, choices, errors, detected, offset, reported)
    result.details["falloff_selection_offsets"] = both  # both figures of every set
    if detected and np.isfinite(every.cost):
        say("the offset on the even and on the odd frames apart")
        offset_halves(result, placing, fit, reported)
        if reconstructed(capture):
            say("the offset with the normals tilted toward and away from the optical axis")
            offset_normal_tilt(result, placing, fit, reported)
        position = np.asarray(result.model.light.position_mm, float)
        far = far_offset(position, median_depth_mm(capture), length_unit_of(capture))
        if far is not None:
            result.warnings.append(far)
    result.details |= {
        "offset_heldout_rmse": offset_fit.heldout_rmse,
        "lens_heldout_rmse": lens_fit.heldout_rmse,
    }
    if right_views:  # the right views the refit on every frame used
        result.details["n_right_views"] = int(right.sum())
    if not detected:
        no_offset(result, offset, stderr, offset_fit, lens_fit, length_unit_of(capture))
    result.seconds = {"total": time.perf_counter() - started}
    if not result.converged:
        result.warnings.append(f"the solver did not converge: {result.status.message}")
    # Without an offset the estimate is the light at the lens with a bound, which an
    # offset's standard error that could not be computed leaves infinite.
    gain = _lobe_gain(result, every, tracks)
    # The bound by the light's own parameter (in the lens plane: x and y).
    name = paper_names(result.model).get(position_name(result.model), "offset_mm")
    bound = reported[:2] if isinstance(result.model.light, LensPlaneLight) else reported
    result = flag_model(result, None if detected else {name: bound}, lobe_gain=gain)
    if Status(result.status) == Status.successful and np.isfinite(every.cost):
        # A lobe that passed: its roughness on the even and on the odd frames apart.
        say("the lobe on the even and on the odd frames apart")
        halves = lobe_halves(result.model, tracks, fit)
        if halves:
            result.details["sigma_halves"] = {
                n: dict(zip(("even_frames", "odd_frames"), v, strict=True))
                for n, v in halves.items()
            }
            result = flag_model(
                result, None if detected else {name: bound}, lobe_gain=gain, halves=halves
            )
    if np.isfinite(every.cost):
        say("each frame's brightness against the other frames'")
        check_frames_brightness(
            result,
            result.model,
            tracks,
            lambda undone: fit(
                [result.model], undone, freeze=() if detected else (position_name(result.model),)
            ),
            [frame.name for frame in capture.capture.frames],
        )
    return result


def _lobe_gain(result, every, tracks) -> float | None:
    """What the lobes bring under the fitted light where they show (at least one 8-bit
    level): 1 - RMSE / RMSE of the diffuse term alone (Lambertian, or the fitted model's
    diffuse lobe with its shape refitted) under the same light (held) on the same tracks,
    each point's albedo eliminated (`lobe_gain_where_it_shows`); None where the refit on
    every frame did not give a finite cost."""
    if not np.isfinite(every.cost):
        return None
    light = result.model.light
    diffuse = result.model.brdf.lobes[diffuse_lobe(result.model)]
    lambertian = ShadingModel(BRDF(diffuse), light, result.model.effects)
    held = [p.name for p in free_parameters(lambertian) if not p.name.startswith("brdf")]
    plain = fit_model_map(
        lambertian, tracks, freeze=held, standard_errors=False, dtype=MAP_LM_DTYPE
    )
    if not np.isfinite(plain.cost) or plain.cost <= 0:
        return None
    gain, shows = lobe_gain_where_it_shows(every.model, plain.model, tracks)
    result.details["lobe_gain"] = gain
    result.details["lobe_gain_all_observations"] = 1 - math.sqrt(every.cost / plain.cost)
    result.details["lobe_shows_observations"] = shows
    result.details["lambertian_same_light_rmse_all_frames"] = plain.rmse["calibration"]
    return gain
