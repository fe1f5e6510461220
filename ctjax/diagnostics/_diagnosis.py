"""The result of `ctjax diagnose`: the base model and every candidate judged on held-out
frames, the verdict, how far the held-out samples determine it, and their JSON."""

import dataclasses

from .._result import Estimate
from ..fitting import ShadingModel
from ..heldout import HeldOut, HeldOutTracks
from ._compared import TOLD_APART_Z

# A candidate "explains the data" when it lowers the held-out RMSE by at least this
# fraction. The held-out frames are the guard against fitting noise: on captures with
# nothing hidden the best candidate improved by 0.0-0.1% (seven `ctjax synth` captures,
# textured and not, 160x128 and 320x256). The noise floor does not veto a verdict: under
# the albedo map on textured images it also counts the texture's interpolation across
# views and reads high (1.41 levels for 1 level of noise at 320x256), and a hidden ambient
# term brought the held-out RMSE from 1.36 to 1.31 levels, below that floor, where the
# earlier rule (the base at least 5% above the floor) said "none".
MATERIAL_IMPROVEMENT = 0.03


@dataclasses.dataclass
class Diagnosis:
    """The base model and every candidate, each an `Estimate` judged on held-out frames.

    A candidate's `details` hold its `effect` (name), its `improvement` (fraction of the
    base's held-out RMSE), the `params` it introduced, the per-frame parameters it held at
    the base's values (`frozen`), the LM `steps` of its best start and the `seconds` its fit
    and judgement took; candidates
    are sorted best first. `heldout` is the split they were all judged on (`HeldOut`, or
    `HeldOutTracks` under the map): what is left of a model's residual there is
    `heldout_budget(diagnosis.heldout, model)`.
    """

    base: Estimate
    noise_floor: float
    candidates: list[Estimate]
    verdict: str
    seconds: float
    # The held-out split every model was judged on (`HeldOut` or `HeldOutTracks`).
    heldout: "HeldOut | HeldOutTracks | None" = None
    # What the user should know about the diagnosis as a whole (why the albedo map was not
    # possible where some frames lack a pose or depth, `why_no_albedo_map`).
    warnings: list[str] = dataclasses.field(default_factory=list)
    # The best candidate where it improves on the base, verdict or not (`effect`,
    # `improvement`, and `z`: its gain in standard errors, `compared`), and the others that
    # predict the held-out frames within `TOLD_APART_Z` standard errors of it (`close`,
    # each with its `z` behind the best): what these frames cannot tell apart.
    leading: dict | None = None
    close: list[dict] = dataclasses.field(default_factory=list)

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
                    "seconds": c.details.get("seconds"),
                    "steps": c.details.get("steps"),
                }
                for c in self.candidates
            ],
            "verdict": self.verdict,
            "verdict_status": self.verdict_status,
            "leading": self.leading,
            "close": list(self.close),
            "warnings": list(self.warnings),
        }

    @property
    def verdict_status(self) -> str | None:
        """How far the held-out samples determine the verdict: `determined` (its gain over
        the base at least `TOLD_APART_Z` standard errors, and no other candidate within that
        of it), `ambiguous` (ahead of the base, and the candidates in `close` as good),
        `not_determined` (its gain within the spread other samples could give), `not_paired`
        (judged on other samples than the base's: the `albedo_texture` candidate of a
        one-albedo diagnosis, on the map's tracked views); None where the verdict is none."""
        if self.verdict == "none" or self.leading is None:
            return None
        if "judged_on" in self.leading:
            return "not_paired"
        z = self.leading["z"]
        if z is None or z < TOLD_APART_Z:
            return "not_determined"
        return "ambiguous" if self.close else "determined"

    def comparison(self) -> list[str]:
        """What the held-out frames say of the leading candidates beyond the verdict, in
        words: the best one where it is under the verdict's line, and those as good."""
        lines, leading = [], self.leading
        if leading is not None and self.verdict == "none":
            lines.append(
                f"leading candidate: {leading['effect']}, held-out RMSE "
                f"{100 * leading['improvement']:.1f}% lower ({_in_errors(leading['z'])}), "
                f"under the {100 * MATERIAL_IMPROVEMENT:g}% a verdict needs"
            )
        if self.verdict_status == "not_paired":
            lines.append(
                f"the verdict is not paired with the base: {self.verdict} is judged on the "
                f"{leading['judged_on']}'s tracked views, the base on its own samples, so its "
                f"{100 * leading['improvement']:.1f}% lower held-out RMSE is not tested sample "
                f"by sample (--albedo {leading['judged_on']} diagnoses every candidate that way)"
            )
        if self.verdict_status == "not_determined":
            lines.append(
                f"the verdict is not determined: {self.verdict}'s held-out RMSE is "
                f"{100 * leading['improvement']:.1f}% lower, {_in_errors(leading['z'])} of "
                f"the difference, under the {TOLD_APART_Z:g} that tell it from the base"
            )
        if self.close:
            named = ", ".join(
                f"{c['effect']} ({100 * c['improvement']:.1f}% lower, {_in_errors(c['z'])} behind)"
                for c in self.close
            )
            lines.append(
                f"as good on the held-out frames as {leading['effect']} (within "
                f"{TOLD_APART_Z:g} standard errors): {named}; these frames do not tell them apart"
            )
        return lines

    @property
    def best_model(self) -> ShadingModel:
        for c in self.candidates:
            if c.details["effect"] == self.verdict:
                return c.model
        return self.base.model


def _in_errors(z) -> str:
    return "no spread to judge it by" if z is None else f"{z:.1f} standard errors"
