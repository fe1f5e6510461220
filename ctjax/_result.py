"""What every estimator returns: one result shape (optimistix's `Solution`, for captures).

`ctjax.fitting.fit_model`, `ctjax.estimation.fit_capture`, the near light, the light field,
the diagnostics' base and candidate fits and the evaluation's models all return an
`Estimate`: the fitted model (never a dict), its errors on the frames it was fitted on and
on held-out frames, the noise floor, a `Status`, warnings, timings, and the figures and
per-pixel maps particular to the estimator. Its JSON is built from the model by walking it
(`ctjax.to_json`), so a new lobe, light or effect appears in every output with no edit.
"""

import dataclasses
import math

import numpy as np

from ._json import named_parameters, to_json
from ._status import Status


@dataclasses.dataclass
class Estimate:
    """A fitted model and how well it explains the data.

    - `model`: the fitted `ShadingModel` (or a `BRDF`, for measured BRDF data).
    - `rmse`: root-mean-square error per split of the data (`"calibration"`, `"heldout"`,
      `"ring"`...), in `unit` (8-bit levels for images).
    - `status`: how the solve ended (`Status`); per-pixel statuses are in `arrays`.
    - `noise_floor`: the measurement noise estimated from the data (same unit), or None.
    - `frames`: frame indices per split (`"calibration"`, `"heldout"`).
    - `warnings`: what the user must know, one sentence each.
    - `seconds`: wall-clock time per stage.
    - `details`: JSON-ready figures particular to the estimator (standard errors, counts,
      the alternatives compared...).
    - `arrays`: per-pixel maps (a light field's directions, per-pixel status...).
    - `cost`: sum of squared residuals in the data's units (linear intensity), for solvers.
    """

    model: object
    rmse: dict[str, float] = dataclasses.field(default_factory=dict)
    status: Status = Status.successful
    noise_floor: float | None = None
    frames: dict[str, list[int]] = dataclasses.field(default_factory=dict)
    warnings: list[str] = dataclasses.field(default_factory=list)
    seconds: dict[str, float] = dataclasses.field(default_factory=dict)
    details: dict = dataclasses.field(default_factory=dict)
    arrays: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    cost: float = math.nan
    unit: str = "8-bit levels"

    @property
    def converged(self) -> bool:
        return Status(self.status).converged

    @property
    def calibration_rmse(self) -> float:
        return self.rmse.get("calibration", math.nan)

    @property
    def heldout_rmse(self) -> float:
        return self.rmse.get("heldout", math.nan)

    def to_json(self) -> dict:
        """The model's named parameters (`rho_tilde`, `F_tilde`, `sigma`, `offset_mm`...),
        `rgb_rmse_<split>`, `noise_floor`, `status`, the frames, the estimator's details,
        `warnings`, `seconds`, and the whole model under `shading_model`."""
        out = dict(named_parameters(self.model))
        for split, value in self.rmse.items():
            out[f"rgb_rmse_{split}"] = finite_or_none(value)
        if self.noise_floor is not None:
            out["noise_floor"] = finite_or_none(self.noise_floor)
        out["status"] = Status(self.status).name
        for split, frames in self.frames.items():
            out[f"{split}_frames"] = list(frames)
        out.update(self.details)
        out["units"] = out.get("units", f"rgb_rmse and noise_floor in {self.unit}")
        out["warnings"] = list(self.warnings)
        out["seconds"] = {k: round(float(v), 2) for k, v in self.seconds.items()}
        out["shading_model"] = to_json(self.model)
        return out


def finite_or_none(value) -> float | None:
    """`value` as a JSON number, None where it is not finite (JSON has no NaN)."""
    value = float(value)
    return value if math.isfinite(value) else None
