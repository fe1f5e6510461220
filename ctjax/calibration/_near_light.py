"""A physical near-light model of the laparoscope (beyond the paper, section 5's alternative).

The light guide is a point light at an unknown offset from the lens, optionally with
inverse-square and angular (spot) falloff, fitted jointly with the BRDF by Levenberg-Marquardt
over all calibration frames: a handful of global parameters instead of two angles per pixel.
Which falloffs the data show is decided on held-out frames. The light's intensity is folded
into rho_tilde and F_tilde, as the paper does (it is not separable from them).
"""

import itertools
import time
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._errors import CtjaxError
from .._json import falloff_json
from .._result import Estimate
from ..fitting import (
    LEVENBERG_MARQUARDT,
    ShadingModel,
    fit_model,
    paper_model,
    pixel_columns,
    pixel_predict,
    roughness_variants,
)
from ..heldout import HeldOut, median_depth_mm, simplest_within
from ..io import Capture
from ..lights import AbstractFalloff, InverseSquare, PointLight, SpotFalloff
from ..observations import Observations

# Starting offsets (mm, camera frame): the fit is not convex in the light's position.
OFFSET_STARTS = ((3.0, 0.0, 0.0), (-3.0, 0.0, 0.0), (0.0, 3.0, 0.0), (0.0, -3.0, 0.0))


def falloff_choices(capture: "Capture | Observations") -> list[tuple[AbstractFalloff, ...]]:
    """Every subset of inverse-square (referenced at the working distance) and spot falloff:
    what `calibrate_near_light` compares by default."""
    factors = (InverseSquare(median_depth_mm(capture)), SpotFalloff(2.0))
    return [c for r in range(len(factors) + 1) for c in itertools.combinations(factors, r)]


def _name(falloff: tuple[AbstractFalloff, ...]) -> str:
    return "+".join(f.name for f in falloff) or "none"


def _starts(falloff: tuple[AbstractFalloff, ...]) -> list[ShadingModel]:
    starts = []
    for offset in OFFSET_STARTS:
        base = paper_model(1.0, 0.3, 0.2)
        light = PointLight(jnp.asarray(offset, float), falloff=tuple(falloff))
        starts.extend(roughness_variants(eqx.tree_at(lambda m: m.light, base, light)))
    return starts


def calibrate_near_light(
    capture: "Capture | Observations",
    *,
    calibration: int | None = None,
    falloff: tuple[AbstractFalloff, ...] | Sequence[tuple[AbstractFalloff, ...]] | None = None,
    solver: optx.AbstractLeastSquaresSolver = LEVENBERG_MARQUARDT,
    max_samples: int = 12_000,
    heldout_samples: int = 40_000,
    max_steps: int = 100,
    seed: int = 0,
) -> Estimate:
    """Fit the near-light model on the calibration frames; report errors on held-out frames.

    `falloff`: the light's falloff factors (e.g. `(InverseSquare(70.0),)`), or several
    such tuples to choose from; by default every subset of `falloff_choices` is fitted and
    the simplest one within 1% of the lowest held-out RMSE is kept. `solver`: the
    least-squares solver (optimistix's interface).

    Returns an `Estimate` of the `ShadingModel` with its `PointLight`; `details` holds the
    chosen `falloff` (by name, with its parameters) and `falloff_selection`, the held-out
    RMSE of every falloff set tried.
    """
    started = time.perf_counter()
    capture = Observations.of(capture)
    if any(f.depth is None for f in capture.frames):
        raise CtjaxError(f"{capture.root}: the near-light model needs depth for every frame")
    heldout = HeldOut.split(
        capture, calibration, max_samples=max_samples, heldout_samples=heldout_samples, seed=seed
    )
    if falloff is None:
        choices = falloff_choices(capture)
    elif all(isinstance(f, AbstractFalloff) for f in falloff):
        choices = [tuple(falloff)]
    else:
        choices = [tuple(c) for c in falloff]
    for choice in choices:
        for factor in choice:
            if not isinstance(factor, AbstractFalloff):
                raise CtjaxError(f"a falloff must be an AbstractFalloff, got {factor!r}")
    fits = [
        fit_model(
            _starts(choice),
            heldout.train,
            pixel_predict,
            columns=pixel_columns,
            solver=solver,
            max_steps=max_steps,
            refine=3,
        )
        for choice in choices
    ]
    errors = [heldout.heldout_rmse(fit.model) for fit in fits]
    fit = heldout.judge(fits[simplest_within(choices, errors)])
    if not np.isfinite(fit.heldout_rmse):
        raise CtjaxError("the near-light fit did not produce finite estimates")
    fit.details |= {
        "model": "near",
        "intensity_note": "folded into rho_tilde and F_tilde (not separable from them)",
        "falloff": falloff_json(fit.model.light),
        "falloff_selection": {_name(c): round(e, 4) for c, e in zip(choices, errors, strict=True)},
    }
    fit.seconds = {"total": time.perf_counter() - started}
    if not fit.converged:
        fit.warnings.append(f"the solver did not converge: {fit.status.message}")
    return fit
