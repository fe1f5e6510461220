"""The near light with the paper's one albedo (`calibrate_near_light(albedo="uniform")`).

Each falloff set is fitted with the light's offset free and with the light at the lens, and
judged on the held-out frames as it would be reported: at the lens unless its offset
predicts them `SIMPLEST_WITHIN` better. The chosen set's offset is reported only where the
data show it: its standard error (Gauss-Newton, `ctjax.fitting.standard_errors`) puts it
more than 2 from the lens and it predicts the held-out frames better than the light at the
lens; otherwise the light at the lens is the estimate, with the bound an offset below which
the data cannot tell from none (as `near_light_map` does with the albedo map).
"""

import time
from collections.abc import Sequence

import numpy as np

from .._determined import flag_model
from .._errors import CtjaxError
from .._json import falloff_json, paper_names
from .._result import Estimate
from .._status import Status
from .._threads import in_order
from .._units import length_unit_of
from ..fitting import fit_model, pixel_columns, pixel_predict, standard_errors
from ..heldout import SIMPLEST_WITHIN, HeldOut, simplest_within
from ..lights import AbstractFalloff, LensPlaneLight
from ..lobes import Lambertian
from ..observations import Observations
from ..solvers import Solver
from ._frames_brightness import check_pixel_brightness
from ._lobe_halves import pixel_lobe_halves
from ._near_light_models import (
    at_the_lens,
    falloff_name,
    falloff_sets,
    near_light_starts,
    no_offset,
    offset_axes_of,
    position_name,
    position_stderr,
    warn_of_misfit,
)


def near_light_uniform(
    capture: Observations,
    *,
    calibration: int | None,
    falloff: tuple[AbstractFalloff, ...] | Sequence[tuple[AbstractFalloff, ...]] | None,
    solver: Solver,
    max_samples: int,
    heldout_samples: int,
    max_steps: int,
    seed: int,
    say,
    workers: int,
    diffuse: type[Lambertian],
    offset_axes: str,
    effects: tuple = (),
) -> Estimate:
    """`calibrate_near_light` with one albedo (its arguments; `say` its progress)."""
    started = time.perf_counter()
    heldout = HeldOut.split(
        capture, calibration, max_samples=max_samples, heldout_samples=heldout_samples, seed=seed
    )
    choices = falloff_sets(capture, falloff)
    say(f"fitting {len(choices)} falloff set(s) on frames {heldout.calibration}, one albedo")

    def fit(starts, **fixed):
        return fit_model(
            starts,
            heldout.train,
            pixel_predict,
            columns=pixel_columns,
            solver=solver,
            max_steps=max_steps,
            refine=3,
            **fixed,
        )

    def fit_choice(choice):
        """The set with its offset and at the lens, judged as it would be reported."""
        offset = fit(near_light_starts(choice, capture, diffuse, offset_axes, effects))
        lens_starts = at_the_lens(choice, diffuse, offset_axes, effects)
        lens = fit(lens_starts, freeze=(position_name(offset.model),))
        pair = heldout.heldout_rmse(offset.model), heldout.heldout_rmse(lens.model)
        return offset, lens, pair

    fits = list(in_order(fit_choice, choices, workers))
    errors = [o if o < (1 - SIMPLEST_WITHIN) * lens else lens for _, _, (o, lens) in fits]
    chosen = simplest_within(choices, errors, observations=heldout.capture)
    offset_fit = heldout.judge(fits[chosen][0], noise_floor=False)
    lens_fit = heldout.judge(fits[chosen][1], noise_floor=False)
    if not np.isfinite(offset_fit.heldout_rmse):
        raise CtjaxError("the near-light fit did not produce finite estimates")
    offset = np.asarray(offset_fit.model.light.position_mm, float)
    say("standard errors of the chosen set's fit")
    # On the calibration fit's model (judging gives per-frame parameters the held-out frames').
    offset_fit.details["stderr"] = standard_errors(
        fits[chosen][0].model, heldout.train, pixel_predict
    )
    reported = position_stderr(offset_fit.details["stderr"], offset_fit.model, [None] * 3)
    stderr = np.asarray([np.inf if e is None else e for e in reported], float)
    fitted = stderr > 0  # the axis in the lens plane is not
    significant = bool(
        np.all(np.isfinite(stderr)) and np.linalg.norm(offset[fitted] / stderr[fitted]) > 2
    )
    better = offset_fit.heldout_rmse < (1 - SIMPLEST_WITHIN) * lens_fit.heldout_rmse
    detected = significant and better
    result = offset_fit
    if not detected:
        result = lens_fit
        lens = fits[chosen][1].model
        result.details["stderr"] = standard_errors(
            lens, heldout.train, pixel_predict, freeze=(position_name(lens),)
        )
    result.noise_floor = heldout.noise_floor(result.model)
    # The shared sinus with one albedo: 51.6 levels held out, 32x its noise floor, and an
    # offset of 0.2 working distances at over 50 standard errors (the map's fit: 22.8 levels).
    warn_of_misfit(result, "on textured tissue one albedo is the wrong model: albedo='map'")
    unit = length_unit_of(capture)
    result.details |= {
        "model": "near",
        "albedo": "uniform",
        "intensity_note": "folded into rho_tilde and F_tilde (not separable from them)",
        "falloff": falloff_json(result.model.light),
        "falloff_selection": {
            falloff_name(c): round(e, 4) for c, e in zip(choices, errors, strict=True)
        },
        "falloff_selection_offsets": {
            falloff_name(c): {"fitted_offset": round(o, 4), "at_the_lens": round(lens, 4)}
            for c, (_, _, (o, lens)) in zip(choices, fits, strict=True)
        },
        "offset_detected": detected,
        "offset_mm": np.asarray(result.model.light.position_mm, float).tolist(),
        "offset_axes": offset_axes_of(result.model),
        "offset_fitted_mm": offset.tolist(),
        "offset_stderr_mm": reported,  # None where the data do not determine it
        "offset_heldout_rmse": offset_fit.heldout_rmse,
        "lens_heldout_rmse": lens_fit.heldout_rmse,
        "length_unit": unit,
    }
    if not detected:
        no_offset(result, offset, stderr, offset_fit, lens_fit, unit)
    result.seconds = {"total": time.perf_counter() - started}
    if not result.converged:
        result.warnings.append(f"the solver did not converge: {result.status.message}")
    bounds = None
    if not detected:
        # The bound by the light's own parameter (in the lens plane: x and y).
        name = paper_names(result.model).get(position_name(result.model), "offset_mm")
        bound = reported[:2] if isinstance(result.model.light, LensPlaneLight) else reported
        bounds = {name: bound}
    result = flag_model(result, bounds)
    calibrated = fits[chosen][0 if detected else 1].model
    if Status(result.status) == Status.successful:
        # A lobe that passed: its roughness on the even and on the odd calibration frames.
        say("the lobe on the even and on the odd calibration frames apart")
        halves = pixel_lobe_halves(
            calibrated, heldout.train, lambda starts, samples, **fixed: fit_model(
                starts, samples, pixel_predict, columns=pixel_columns, solver=solver,
                max_steps=max_steps, **fixed,
            ),
        )  # fmt: skip
        if halves:
            result.details["sigma_halves"] = {
                n: dict(zip(("even_frames", "odd_frames"), v, strict=True))
                for n, v in halves.items()
            }
            result = flag_model(result, bounds, halves=halves)
    say("each calibration frame's brightness against the model's")
    check_pixel_brightness(
        result,
        calibrated,
        heldout.train,
        lambda undone: fit_model(
            calibrated,
            undone,
            pixel_predict,
            columns=pixel_columns,
            solver=solver,
            max_steps=max_steps,
            freeze=() if detected else (position_name(calibrated),),
        ),
        [frame.name for frame in capture.frames],
    )
    return result
