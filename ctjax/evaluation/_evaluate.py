"""`ctjax evaluate`: the paper's evaluation (section 7) of Lambertian against Cook-Torrance.

Both models are fitted on the first N frames (calibration) and compared on the rest (test):
(i) RGB error on the calibration frames, (ii) on the test frames, (iii) shape from shading
on the test frames, brought to metric scale by the known bounding-box volume, against the
capture's depth.
"""

import dataclasses
import math
import time
from collections.abc import Callable

import cv2
import numpy as np

from .._errors import CtjaxError
from ..diagnostics._diagnose import split_frames
from ..fitting import (
    ShadingModel,
    capture_samples,
    fit_model,
    pixel_columns,
    pixel_predict,
    rmse_levels,
)
from ..io import Capture
from ..lights import ColocatedLight
from ..lobes import BRDF, Lambertian
from ._pyramid import block_reduce, reduced
from ._scale import bounding_box_volume
from ._sfs import ShapeFromShading, sfs_cook_torrance, sfs_refined, sfs_tsai_shah

LIGHTS = ("near", "colocated", "field")
# Shape from shading runs on the frame reduced so that it is at most this wide (its sparse
# Gauss-Newton solve grows faster than the pixel count).
SFS_MAX_WIDTH = 160
# "Near highlights": within this many full-resolution pixels of the specular set S.
HIGHLIGHT_RADIUS_PX = 12


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
        return _mean(np.abs(shape.depth - self.reference)[self.mask])

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
    light: str
    calibration_frames: list[int]
    test_frames: list[int]
    lambertian: ShadingModel
    cook_torrance: ShadingModel
    rgb_rmse: dict  # model -> {"calibration": levels, "test": levels}
    shapes: list[FrameShape]
    timings: dict
    notes: list[str]

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

    def to_json(self) -> dict:
        out = {
            "light": self.light,
            "calibration_frames": self.calibration_frames,
            "test_frames": self.test_frames,
        }
        for model in ("lambertian", "cook_torrance"):
            out[f"{model}_rgb_rmse_calibration"] = self.rgb_rmse[model]["calibration"]
            out[f"{model}_rgb_rmse_test"] = self.rgb_rmse[model]["test"]
        for model in ("lambertian", "cook_torrance", "per_pixel"):
            if model == "per_pixel" and not any(s.per_pixel for s in self.shapes):
                continue
            errors = self.sfs_errors(model)
            near = self.sfs_errors(model, "near_highlight")
            key = "cook_torrance_per_pixel" if model == "per_pixel" else model
            out[f"{key}_sfs_error_mm"] = _mean(errors)
            out[f"{key}_sfs_error_median_mm"] = _median(errors)
            out[f"{key}_sfs_error_near_highlights_mm"] = _mean(near)
        out["units"] = (
            "rgb_rmse: 8-bit levels over unsaturated pixels with geometry; sfs_error: mean "
            "(or median) |depth - reference depth|, mm, test frames, after scaling each SfS "
            "surface to the reference's bounding-box volume. SfS: lambertian = Tsai-Shah; "
            "cook_torrance = Tsai-Shah's formulation with the Cook-Torrance reflectance map "
            "(joint, coarse to fine); cook_torrance_per_pixel = the paper's refinement of "
            "Tsai-Shah's normals per pixel (eq. 9), integrated"
        )
        out["models"] = {
            "lambertian": {"rho_tilde": _weights(self.lambertian, 0)},
            "cook_torrance": {
                "rho_tilde": _weights(self.cook_torrance, 0),
                "F_tilde": _weights(self.cook_torrance, 1),
                "sigma": float(self.cook_torrance.brdf.lobes[1].distribution.sigma),
                "light": type(self.cook_torrance.light).__name__,
            },
        }
        out["sfs_frames"] = [shape.to_json() for shape in self.shapes]
        out["timings_s"] = {k: round(v, 2) for k, v in self.timings.items()}
        out["notes"] = self.notes
        return out


def _mean(values) -> float | None:
    return float(np.mean(values)) if len(values) else None


def _median(values) -> float | None:
    return float(np.median(values)) if len(values) else None


def _weights(model: ShadingModel, lobe: int) -> list[float]:
    return [round(float(w), 6) for w in np.asarray(model.brdf.lobes[lobe].weight)]


def fit_lambertian(capture: Capture, frames: list[int], max_samples: int = 40_000):
    """The Lambertian model (rho_tilde, light at the camera) fitted to every usable pixel of
    `frames`: linear, so the closed form is the least-squares solution."""
    samples = capture_samples(capture, frames, max_samples=max_samples)
    start = ShadingModel(BRDF(Lambertian(1.0)), ColocatedLight())
    return fit_model(start, samples, pixel_predict, columns=pixel_columns, max_steps=20)


def fit_cook_torrance(capture: Capture, calibration: int, light: str) -> ShadingModel:
    """Cook-Torrance with its light, fitted on the calibration frames."""
    if light == "near":
        from ..calibration import calibrate_near_light

        return calibrate_near_light(capture, calibration=calibration).model
    if light == "field":
        from ..calibration import calibrate_light_field  # the paper's light field (eq. 7-8)

        return calibrate_light_field(capture, calibration=calibration).model
    if light == "colocated":
        from ..estimation._capture_fit import MaskOptions, fit_capture
        from ..fitting import paper_model

        subset = dataclasses.replace(capture, frames=capture.frames[:calibration])
        fit = fit_capture(subset, MaskOptions(ring_px=10))
        return paper_model(fit["rho_tilde"], fit["F_tilde"], fit["sigma"])
    raise CtjaxError(f"unknown light model {light!r}; known: {', '.join(LIGHTS)}")


def _near_highlight(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    from ..estimation._specular_set import specular_sets

    specular = specular_sets(image, mask).specular
    if not specular.any():
        return np.zeros_like(mask)
    distance = cv2.distanceTransform((~specular).astype(np.uint8), cv2.DIST_L2, 5)
    return distance <= HIGHLIGHT_RADIUS_PX


def frame_shapes(
    capture: Capture,
    index: int,
    lambertian: ShadingModel,
    cook_torrance: ShadingModel,
    max_width: int = SFS_MAX_WIDTH,
    reference: Capture | None = None,
    per_pixel: bool = False,
) -> FrameShape:
    """Both SfS of one frame against its depth (or `reference`'s), at reduced resolution."""
    frame = (reference or capture).frames[index]
    if frame.depth is None:
        raise CtjaxError(f"frame {frame.name}: SfS is compared with depth; the frame has none")
    factor = max(1, math.ceil(capture.camera.width / max_width))
    camera = reduced(capture.camera, factor)
    valid = frame.geometry_mask
    mask = block_reduce(valid, factor, np.all)
    image = block_reduce(frame.image, factor)
    reference = np.where(mask, block_reduce(np.where(valid, frame.depth, 0.0), factor), np.nan)
    near = block_reduce(_near_highlight(frame.image, valid), factor, np.any)
    if mask.sum() < 9:
        raise CtjaxError(f"frame {frame.name}: too few pixels with depth for SfS")
    volume = bounding_box_volume(reference, mask, camera)
    rho = np.asarray(lambertian.brdf.lobes[0].weight)
    tsai_shah, log_depth = sfs_tsai_shah(image, mask, camera, rho, volume)
    joint, _ = sfs_cook_torrance(image, mask, camera, cook_torrance, volume)
    paper = None
    if per_pixel:
        paper = sfs_refined(image, mask, camera, cook_torrance, log_depth, volume, rounds=1)
    return FrameShape(frame.name, image, reference, tsai_shah, joint, mask, near, paper)


def evaluate(
    capture: Capture,
    *,
    calibration: int | None = None,
    light: str = "near",
    sfs: bool = True,
    cook_torrance: ShadingModel | None = None,
    reference: Capture | None = None,
    per_pixel_sfs: bool = False,
    progress: Callable[[str], None] = lambda message: None,
) -> Evaluation:
    """Fit Lambertian and Cook-Torrance (+ `light`: "near", "colocated" or "field") on the
    calibration frames and evaluate both on the test frames (RGB error and SfS).

    `cook_torrance`: an already fitted model (its light named by `light`), used as is.
    `reference`: the capture whose depth the SfS is compared with (default: `capture`'s own;
    e.g. ground truth when `capture`'s shape came from structure-from-motion).
    `per_pixel_sfs`: also run the paper's per-pixel Cook-Torrance SfS (eq. 9 on Tsai-Shah's
    normals) and report it beside the joint one."""
    if light not in LIGHTS:
        raise CtjaxError(f"unknown light model {light!r}; known: {', '.join(LIGHTS)}")
    missing = [f.name for f in capture.frames if f.depth is None or f.normals is None]
    if missing:
        raise CtjaxError(
            f"{capture.root}: evaluate needs depth and normals for every frame (missing for "
            f"{', '.join(missing[:5])}); run `ctjax reconstruct` first"
        )
    calib, test = split_frames(len(capture), calibration, source=capture.root)
    timings = {}
    tic = time.perf_counter()
    progress(f"fitting the Lambertian model on frames {calib}...")
    lambertian = fit_lambertian(capture, calib)
    timings["lambertian_fit"] = time.perf_counter() - tic
    tic = time.perf_counter()
    if cook_torrance is None:
        progress(f"fitting Cook-Torrance with the {light} light on frames {calib}...")
        cook_torrance = fit_cook_torrance(capture, len(calib), light)
    timings["cook_torrance_fit"] = time.perf_counter() - tic
    tic = time.perf_counter()
    rgb = {}
    for name, model in (("lambertian", lambertian.model), ("cook_torrance", cook_torrance)):
        rgb[name] = {
            split: float(rmse_levels(model, capture_samples(capture, frames), pixel_predict))
            for split, frames in (("calibration", calib), ("test", test))
        }
    timings["rgb_error"] = time.perf_counter() - tic
    shapes = []
    if sfs:
        tic = time.perf_counter()
        for index in test:
            progress(f"shape from shading of test frame {capture.frames[index].name}...")
            shapes.append(
                frame_shapes(
                    capture,
                    index,
                    lambertian.model,
                    cook_torrance,
                    reference=reference,
                    per_pixel=per_pixel_sfs,
                )
            )
        timings["sfs"] = time.perf_counter() - tic
    notes = []
    if lambertian.status != "successful":
        notes.append(f"Lambertian fit: solver status {lambertian.status}")
    return Evaluation(
        light, calib, test, lambertian.model, cook_torrance, rgb, shapes, timings, notes
    )
