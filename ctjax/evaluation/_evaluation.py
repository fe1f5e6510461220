"""The result of `ctjax evaluate`: both models on the calibration and the test frames, the
test frames' shapes from shading, and their JSON."""

import dataclasses

import numpy as np

from .._json import named_parameters
from .._result import Estimate
from .._status import Status
from .._units import METRIC, label
from ._lobes import lobes_judged
from ._sfs import ShapeFromShading

# The models an evaluation fits, in the order the gain is split: the paper's Lambertian, the
# same under Cook-Torrance's light, Cook-Torrance's diffuse term alone under it, and itself.
MODELS = ("lambertian", "lambertian_same_light", "diffuse_same_light", "cook_torrance")


@dataclasses.dataclass
class FrameShape:
    """One test frame's SfS at reduced resolution: the image, the reference depth and both
    SfS depths (mm), the pixels compared and those near a highlight."""

    name: str
    image: np.ndarray
    reference: np.ndarray
    lambertian: ShapeFromShading
    cook_torrance: ShapeFromShading
    mask: np.ndarray
    near_highlight: np.ndarray
    # The paper's Cook-Torrance SfS (Tsai-Shah's normals refined per pixel, eq. 9), if run.
    per_pixel: ShapeFromShading | None = None

    def error_mm(self, shape: ShapeFromShading) -> float | None:
        """Mean |depth - reference| (mm) of one SfS over the compared pixels."""
        return mean_or_none(np.abs(shape.depth - self.reference)[self.mask])

    def to_json(self) -> dict:
        out = {
            "name": self.name,
            "pixels": int(self.mask.sum()),
            "near_highlight_pixels": int((self.mask & self.near_highlight).sum()),
            "lambertian_mm": self.error_mm(self.lambertian),
            "cook_torrance_mm": self.error_mm(self.cook_torrance),
            "cook_torrance_rms_levels": self.cook_torrance.rms_levels,
        }
        if self.per_pixel is not None:
            out["cook_torrance_per_pixel_mm"] = self.error_mm(self.per_pixel)
            out["cook_torrance_per_pixel_not_converged"] = self.per_pixel.not_converged
        return out


@dataclasses.dataclass
class Evaluation:
    """Both models (`Estimate`s, their `rmse` on the calibration and the test frames) and
    the shapes from shading of the test frames."""

    calibration_frames: list[int]
    test_frames: list[int]
    lambertian: Estimate
    cook_torrance: Estimate
    shapes: list[FrameShape]
    timings: dict
    notes: list[str]
    albedo: str = "uniform"
    # Lambertian under Cook-Torrance's fitted light (held): the two differ by the lobe alone.
    lambertian_same_light: Estimate | None = None
    length_unit: str = METRIC
    # A stereo capture's right views of the calibration frames (`ctjax.heldout.RightViews`):
    # per model, its RMSE on them and on the left views of the same points.
    right_views: dict | None = None
    # Cook-Torrance's diffuse term alone under its light (held), its shape fitted: where
    # that term is not Lambert's, it and the lobe differ by the lobe alone.
    diffuse_same_light: Estimate | None = None
    # What is left of each model's test-frame residual under the map
    # (`ctjax.diagnostics.heldout_budget`'s JSON, by model name).
    residual_budget: dict | None = None
    # The lobe about every point's own facet under Cook-Torrance's light
    # (`ctjax.fitting.facet_lobe`'s JSON), where asked for.
    facets: dict | None = None
    # Each frame's RMSE under both models and the frames the others do not predict
    # (`ctjax.heldout.frame_consistency`'s JSON), under the map.
    frames_rmse: dict | None = None

    @property
    def light(self) -> str:
        """Cook-Torrance's light: "near", "field", "colocated" (or the light's class)."""
        return self.cook_torrance.details.get(
            "light", type(self.cook_torrance.model.light).__name__
        )

    def sfs_errors(self, model: str, where: str = "all") -> np.ndarray:
        """|SfS depth - reference| (mm) over the test frames' pixels (or those near a
        highlight) for `model`: "lambertian", "cook_torrance" or "per_pixel"."""
        errors = []
        for shape in self.shapes:
            selected = shape.mask if where == "all" else shape.mask & shape.near_highlight
            estimate = getattr(shape, model)
            if estimate is not None:
                errors.append(np.abs(estimate.depth - shape.reference)[selected])
        return np.concatenate(errors) if errors else np.zeros(0)

    def gain(self) -> dict:
        """Cook-Torrance's gain over the paper's Lambertian on the test frames, split into its
        light's (Lambertian at the camera -> Lambertian under Cook-Torrance's light and image
        effects), its
        diffuse term's where that is not Lambert's (-> that term alone under the same light)
        and its lobe's (-> Cook-Torrance), in levels."""
        test = {n: getattr(self, n).rmse["test"] for n in MODELS if getattr(self, n) is not None}
        out = {"total_levels": test["lambertian"] - test["cook_torrance"]}
        lit = test.get("lambertian_same_light", test["lambertian"])
        if "lambertian_same_light" in test:
            out["light_levels"] = test["lambertian"] - lit
        if "diffuse_same_light" in test:
            out["diffuse_levels"] = lit - test["diffuse_same_light"]
            out["lobe_levels"] = test["diffuse_same_light"] - test["cook_torrance"]
        elif "lambertian_same_light" in test:
            out["lobe_levels"] = lit - test["cook_torrance"]
        out["note"] = (
            "test-frame RGB RMSE: Lambertian (light at the camera) minus Cook-Torrance; "
            "light_levels: what Cook-Torrance's light (offset, falloff) and its fitted image "
            "effects (held) bring to the Lambertian model alone; diffuse_levels: what "
            "Cook-Torrance's diffuse term (when not Lambert's) brings under that light; "
            "lobe_levels: what the specular lobe brings under that same light and diffuse term"
        )
        return out

    def to_json(self) -> dict:
        out = {
            "light": self.light,
            "albedo": self.albedo,
            "calibration_frames": self.calibration_frames,
            "test_frames": self.test_frames,
        }
        for model in MODELS:
            if getattr(self, model) is None:
                continue
            rmse = getattr(self, model).rmse
            out[f"{model}_rgb_rmse_calibration"] = rmse["calibration"]
            out[f"{model}_rgb_rmse_test"] = rmse["test"]
        out["gain"] = self.gain()
        if self.residual_budget is not None:
            out["residual_budget"] = self.residual_budget
        if self.right_views is not None:
            out["right_views"] = self.right_views
        if self.facets is not None:
            out["facets"] = self.facets
        if self.frames_rmse is not None:
            out["frames_rmse"] = self.frames_rmse
        for model in ("lambertian", "cook_torrance", "per_pixel"):
            if model == "per_pixel" and not any(s.per_pixel for s in self.shapes):
                continue
            errors = self.sfs_errors(model)
            near = self.sfs_errors(model, "near_highlight")
            key = "cook_torrance_per_pixel" if model == "per_pixel" else model
            out[f"{key}_sfs_error_mm"] = mean_or_none(errors)
            out[f"{key}_sfs_error_median_mm"] = mean_or_none(errors, np.median)
            out[f"{key}_sfs_error_near_highlights_mm"] = mean_or_none(near)
        rgb = (
            "8-bit levels over the views of surface points tracked across frames, each "
            "predicted with the model fixed and the point's albedo fitted to its other views "
            "(both models)"
            if self.albedo == "map"
            else "8-bit levels over unsaturated pixels with geometry"
        )
        out["units"] = (
            f"rgb_rmse: {rgb}; sfs_error: mean "
            f"(or median) |depth - reference depth|, {label(self.length_unit)}, test frames, "
            "after scaling each SfS "
            "surface to the reference's bounding-box volume. SfS: lambertian = Tsai-Shah; "
            "cook_torrance = Tsai-Shah's formulation with the Cook-Torrance reflectance map "
            "(joint, coarse to fine); cook_torrance_per_pixel = the paper's refinement of "
            "Tsai-Shah's normals per pixel (eq. 9), integrated"
        )
        out["models"] = {
            "lambertian": named_parameters(self.lambertian.model.brdf),
            **(
                {}
                if self.lambertian_same_light is None
                else {"lambertian_same_light": named_parameters(self.lambertian_same_light.model)}
            ),
            **(
                {}
                if self.diffuse_same_light is None
                else {"diffuse_same_light": named_parameters(self.diffuse_same_light.model)}
            ),
            "cook_torrance": {
                **named_parameters(self.cook_torrance.model.brdf),
                "light": type(self.cook_torrance.model.light).__name__,
                # Not "successful" where the data do not determine its lobe.
                "status": Status(self.cook_torrance.status).name,
                "undetermined": self.cook_torrance.details.get("undetermined", []),
                **(
                    {"effects": named_parameters(self.cook_torrance.model.effects)}
                    if self.cook_torrance.model.effects
                    else {}
                ),
            },
        }
        out["lobes_judged"] = lobes_judged(out)
        out["sfs_frames"] = [shape.to_json() for shape in self.shapes]
        out["timings_s"] = {k: round(v, 2) for k, v in self.timings.items()}
        out["notes"] = self.notes
        return out


def mean_or_none(values, statistic=np.mean) -> float | None:
    return float(statistic(values)) if len(values) else None
