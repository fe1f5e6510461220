"""A physical near-light model of the laparoscope (beyond the paper, section 5's alternative).

The light guide is a point light at an unknown offset from the lens, optionally with
inverse-square and angular (spot) falloff, fitted jointly with the BRDF by Levenberg-Marquardt
over all calibration frames: a handful of global parameters instead of two angles per pixel.
Which falloffs the data show is decided on held-out frames. The light's intensity is folded
into rho_tilde and F_tilde, as the paper does (it is not separable from them).
"""

import dataclasses
import itertools

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._errors import CtjaxError
from ..diagnostics._diagnose import noise_floor_levels, split_frames
from ..fitting import (
    ShadingModel,
    capture_samples,
    fit_model,
    paper_model,
    pixel_columns,
    pixel_predict,
    rmse_levels,
    roughness_variants,
)
from ..fitting._samples import usable_mask
from ..io import Capture
from ..lights import InverseSquare, PointLight, SpotFalloff

# Starting offsets (mm, camera frame): the fit is not convex in the light's position.
OFFSET_STARTS = ((3.0, 0.0, 0.0), (-3.0, 0.0, 0.0), (0.0, 3.0, 0.0), (0.0, -3.0, 0.0))
FALLOFFS = ("inverse_square", "spot")


@dataclasses.dataclass
class NearLightCalibration:
    model: ShadingModel
    falloff: tuple[str, ...]
    calibration_rmse: float
    heldout_rmse: float
    noise_floor: float
    status: str
    calibration_frames: list[int]
    heldout_frames: list[int]
    alternatives: dict  # falloff set -> held-out RMSE

    def to_json(self) -> dict:
        light = self.model.light
        brdf = self.model.brdf
        falloff = {}
        for f in light.falloff:
            if isinstance(f, InverseSquare):
                falloff["inverse_square"] = {"reference_mm": float(f.reference_mm)}
            elif isinstance(f, SpotFalloff):
                falloff["spot"] = {
                    "exponent": float(f.exponent),
                    "axis": np.asarray(f.axis).tolist(),
                }
        return {
            "model": "near",
            "offset_mm": np.asarray(light.position_mm).tolist(),
            "intensity": float(light.intensity),
            "intensity_note": "folded into rho_tilde and F_tilde (not separable from them)",
            "falloff": falloff,
            "rho_tilde": np.asarray(brdf.lobes[0].weight).tolist(),
            "F_tilde": np.asarray(brdf.lobes[1].weight).tolist(),
            "sigma": float(brdf.lobes[1].distribution.sigma),
            "rgb_rmse_calibration": self.calibration_rmse,
            "rgb_rmse_heldout": self.heldout_rmse,
            "noise_floor": self.noise_floor,
            "status": self.status,
            "calibration_frames": self.calibration_frames,
            "heldout_frames": self.heldout_frames,
            "falloff_selection": self.alternatives,
        }


def _starts(falloff: tuple[str, ...], reference_mm: float) -> list[ShadingModel]:
    factors = []
    if "inverse_square" in falloff:
        factors.append(InverseSquare(reference_mm))
    if "spot" in falloff:
        factors.append(SpotFalloff(2.0))
    starts = []
    for offset in OFFSET_STARTS:
        base = paper_model(1.0, 0.3, 0.2)
        light = PointLight(jnp.asarray(offset, float), falloff=tuple(factors))
        starts.extend(roughness_variants(eqx.tree_at(lambda m: m.light, base, light)))
    return starts


def calibrate_near_light(
    capture: Capture,
    *,
    calibration: int | None = None,
    falloff: tuple[str, ...] | None = None,
    max_samples: int = 12_000,
    heldout_samples: int = 40_000,
    max_steps: int = 100,
    seed: int = 0,
) -> NearLightCalibration:
    """Fit the near-light model on the calibration frames; report errors on held-out frames.

    `falloff` fixes the falloffs (a subset of ("inverse_square", "spot")); by default every
    subset is fitted and the simplest one within 1% of the lowest held-out RMSE is kept.
    """
    if any(f.depth is None for f in capture.frames):
        raise CtjaxError(f"{capture.root}: the near-light model needs depth for every frame")
    calib, heldout = split_frames(len(capture), calibration, source=capture.root)
    train = capture_samples(capture, calib, max_samples=max_samples, seed=seed)
    test = capture_samples(capture, heldout, max_samples=heldout_samples, seed=seed + 1)
    depth = np.concatenate([capture.frames[i].depth[usable_mask(capture.frames[i])] for i in calib])
    reference = float(np.median(depth))
    choices = (
        [tuple(falloff)]
        if falloff is not None
        else [c for r in range(len(FALLOFFS) + 1) for c in itertools.combinations(FALLOFFS, r)]
    )
    unknown = set(itertools.chain(*choices)) - set(FALLOFFS)
    if unknown:
        raise CtjaxError(f"unknown falloff {sorted(unknown)}; known: {', '.join(FALLOFFS)}")
    fits = {}
    for choice in choices:
        fit = fit_model(
            _starts(choice, reference),
            train,
            pixel_predict,
            columns=pixel_columns,
            max_steps=max_steps,
            refine=3,
        )
        fits[choice] = (fit, float(rmse_levels(fit.model, test, pixel_predict)))
    # The simplest falloff set whose held-out error is within 1% of the best: a falloff the
    # data do not show fits to ~nothing and would otherwise win on noise.
    lowest = min(v[1] for v in fits.values())
    best = min((c for c in fits if fits[c][1] <= 1.01 * lowest), key=len)
    fit, heldout_rmse = fits[best]
    if not np.isfinite(heldout_rmse):
        raise CtjaxError("the near-light fit did not produce finite estimates")
    return NearLightCalibration(
        fit.model,
        best,
        float(fit.rmse),
        heldout_rmse,
        noise_floor_levels(capture, heldout, fit.model),
        fit.status,
        calib,
        heldout,
        {"+".join(c) or "none": round(v[1], 4) for c, v in fits.items()},
    )
