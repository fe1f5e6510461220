"""The main job, `ctjax demo`: the whole pipeline on a built-in synthetic capture, from images.

synth (a textured laparoscope capture, ground truth kept aside) -> reconstruct (SfM on the
images alone) -> masks (S and S~) -> fit (rho_tilde, F_tilde, sigma; paper section 4) ->
calibrate-light (the near-light model and the paper's light field; section 5) -> evaluate
(Lambertian vs Cook-Torrance, RGB error and shape from shading; section 7). Writes
`report.html` (one self-contained page) and `summary.json`.
"""

import base64
import functools
import html
import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ._errors import CtjaxError
from .calibration import ClosedFormLM, calibrate_light_field, calibrate_near_light, named_falloff
from .calibration._near_light_models import FALLOFF_NAMES
from .estimation import MaskOptions, capture_sets, fit_capture
from .evaluation import evaluate, evaluation_plots
from .io import load_capture
from .sfm import reconstruct
from .synth import SynthOptions, synthesize

# The paper's 3 px ring is thin on bright tissue (highlights rimmed by saturated red).
DEMO_RING_PX = 10
# Enough albedo texture for SfM (SIFT), little enough for the paper's one-albedo model.
DEMO_TEXTURE_CONTRAST = 0.3


def _log(message: str) -> None:
    print(f"[ctjax demo] {message}", flush=True)


class _Steps:
    """Runs the pipeline's steps, logging and timing each."""

    def __init__(self, log: Callable[[str], None]):
        self.log = log
        self.seconds: dict[str, float] = {}

    def __call__(self, name: str, message: str, function, *args, **kwargs):
        self.log(message)
        tic = time.perf_counter()
        result = function(*args, **kwargs)
        self.seconds[name] = round(time.perf_counter() - tic, 2)
        self.log(f"  {name}: {self.seconds[name]:.1f} s")
        return result


def _images_only(capture_dir: Path, out: Path) -> Path:
    """A copy of the capture with its images and camera only (what a laparoscope gives)."""
    if out.exists():
        shutil.rmtree(out)
    (out / "images").mkdir(parents=True)
    shutil.copy2(capture_dir / "camera.json", out / "camera.json")
    for image in sorted((capture_dir / "images").iterdir()):
        shutil.copy2(image, out / "images" / image.name)
    return out


def _figure_inputs(capture, truth, sets, path: Path) -> Path:
    from matplotlib.figure import Figure

    frame, true_frame, s = capture.frames[0], truth.frames[0], sets[0]
    fig = Figure(figsize=(16, 3.6), layout="constrained")
    axes = fig.subplots(1, 4)
    axes[0].imshow(np.clip(frame.image, 0, 1))
    axes[0].set_title(f"input {frame.name}")
    overlay = np.clip(frame.image, 0, 1).copy()
    overlay[s.ring] = (0.1, 0.8, 0.2)
    overlay[s.specular] = (0.1, 0.3, 1.0)
    axes[1].imshow(overlay)
    axes[1].set_title("S (blue) and ring S~ (green)")
    axes[2].imshow(np.where(frame.geometry_mask[..., None], 0.5 - 0.5 * frame.normals, 1.0))
    axes[2].set_title("normals from SfM")
    cosine = np.sum(frame.normals * true_frame.normals, axis=-1)
    error = np.degrees(np.arccos(np.clip(cosine, -1, 1)))
    shown = axes[3].imshow(np.where(frame.geometry_mask, error, np.nan), cmap="magma", vmax=10)
    axes[3].set_title("SfM normal error vs truth (deg)")
    fig.colorbar(shown, ax=axes[3], shrink=0.8)
    for ax in axes:
        ax.set_axis_off()
    fig.savefig(path, dpi=80)
    return path


def _figure_light(field, near, capture, path: Path) -> Path:
    from matplotlib.figure import Figure

    frame = capture.frames[0]
    fig = Figure(figsize=(11, 3.8), layout="constrained")
    axes = fig.subplots(1, 2)
    view, directions = field.arrays["view"], field.arrays["directions"]
    angle = np.degrees(np.arccos(np.clip(np.sum(directions * view, axis=-1), -1, 1)))
    shown = axes[0].imshow(np.where(frame.geometry_mask, angle, np.nan), cmap="viridis")
    axes[0].set_title("light field: angle between L and V (deg)")
    fig.colorbar(shown, ax=axes[0], shrink=0.8)
    step = max(1, capture.camera.width // 24)
    rows, cols = np.mgrid[
        step // 2 : capture.camera.height : step, step // 2 : capture.camera.width : step
    ]
    directions = directions[rows, cols]
    axes[1].imshow(np.clip(frame.image, 0, 1))
    axes[1].quiver(cols, rows, directions[..., 0], directions[..., 1], color="w", angles="xy")
    offset = ", ".join(f"{v:.1f}" for v in near["offset_mm"])
    axes[1].set_title(f"field (x, y) components; near model: offset ({offset}) mm")
    for ax in axes:
        ax.set_axis_off()
    fig.savefig(path, dpi=80)
    return path


def _table(rows: list[tuple]) -> str:
    cells = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table>{cells}</table>"


def _fmt(value) -> str:
    if isinstance(value, list | tuple):
        return "(" + ", ".join(_fmt(v) for v in value) + ")"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _relative(estimate, truth) -> str:
    estimate, truth = np.atleast_1d(estimate), np.atleast_1d(truth)
    if estimate.shape != truth.shape or np.any(truth == 0):
        return ""
    return ", ".join(f"{100 * (e / t - 1):+.1f}%" for e, t in zip(estimate, truth, strict=True))


def _estimate_rows(summary: dict) -> list[tuple]:
    """(estimate, parameter, value, truth, error) for every estimate used downstream."""
    truth = summary["truth"]
    rows = [("estimate", "parameter", "estimated from the images", "truth", "error")]
    estimates = (
        ("BRDF fit (L = V)", summary["brdf_fit"]),
        ("near light (used by the evaluation)", summary["near_light"]),
        ("light field (paper)", summary["light_field"]),
    )
    for name, estimate in estimates:
        for key in ("rho_tilde", "F_tilde", "sigma"):
            value, true = estimate[key], truth[key]
            rows.append((name, key, _fmt(value), _fmt(true), _relative(value, true)))
        # Not "successful" where the data do not determine the lobe (`ctjax._determined`).
        rows.append((name, "status", str(estimate.get("status", "")), "", ""))
    near = summary["near_light"]
    offset = np.asarray(near["offset_mm"]) - np.asarray(truth["light_mm"])
    rows.append(
        (
            "near light (used by the evaluation)",
            "light offset (mm)",
            _fmt(near["offset_mm"]),
            _fmt(truth["light_mm"]),
            f"{np.linalg.norm(offset):.2f} mm",
        )
    )
    field = summary["light_field"]
    rows.append(
        (
            "light field (paper)",
            "median angle L to V (deg)",
            _fmt(field["median_angle_from_view_deg"]),
            _fmt(truth["field_angle_deg"]),
            "",
        )
    )
    return rows


def _true_field_angle(truth, light_mm) -> float:
    """Median angle (deg) between the true light direction and V over the first frame."""
    from ._geometry import points_from_depth

    frame = truth.frames[0]
    point = points_from_depth(truth.camera, frame.depth)[frame.geometry_mask]
    to_light = np.asarray(light_mm, float) - point
    cosine = np.sum(to_light * -point, -1) / (
        np.linalg.norm(to_light, axis=-1) * np.linalg.norm(point, axis=-1)
    )
    return float(np.median(np.degrees(np.arccos(np.clip(cosine, -1, 1)))))


def _warnings(fit: dict, near, field, evaluation) -> list[tuple[str, str]]:
    """Every warning of the pipeline's steps, by step."""
    out = [("fit", w) for w in fit.get("warnings", [])]
    out += [("calibrate-light near", w) for w in near.warnings]
    out += [("calibrate-light field", w) for w in field.warnings]
    out += [("evaluate", n) for n in evaluation.notes]
    return out


# What to look at in each figure of the report.
_CAPTIONS = {
    "inputs": "The input frames with S (blue) and the ring S~ (green) over them: S should "
    "cover the highlights and nothing else; the ring, the tissue just outside them, is "
    "where the BRDF is measured.",
    "light": "The estimated light beside the truth: the light field's per-pixel directions "
    "(their angle from the view direction; near zero everywhere when the light is at the "
    "lens) and the near light's offset.",
    "error_bars": "RGB error of each model on the calibration and the test frames (8-bit "
    "levels; the noise floor is about 1) and its shape-from-shading depth error: "
    "Cook-Torrance's bars should be far lower than Lambertian's, most of all near "
    "highlights.",
    "rgb_residuals": "Where each model fails on a test frame: the residual image (recorded "
    "minus predicted). Lambertian's errors sit on the highlights; structure left in "
    "Cook-Torrance's residuals is an effect the model misses.",
}


def _caption(name: str) -> str:
    if name.startswith("sfs_"):
        frame = name.removeprefix("sfs_")
        return (
            f"Shape from shading of test frame {frame}: depth error maps of Tsai-Shah "
            "(Lambertian) and of the Cook-Torrance SfS against the reference depth; the "
            "Lambertian error concentrates where highlights brighten the image."
        )
    return _CAPTIONS.get(name, name)


def _write_report(out: Path, summary: dict, figures: dict[str, Path]) -> Path:
    ev = summary["evaluation"]
    sfm, near, field = summary["reconstruction"], summary["near_light"], summary["light_field"]
    parameters = _table(_estimate_rows(summary))
    warnings = "".join(
        f"<li><b>{html.escape(source)}</b>: {html.escape(text)}</li>"
        for source, text in summary["warnings"]
    )
    warnings = f"<ul>{warnings}</ul>" if warnings else "<p>none</p>"
    errors = _table(
        [("", "Lambertian", "Cook-Torrance")]
        + [
            (
                label,
                _fmt(ev[f"lambertian_{key}"]),
                _fmt(ev[f"cook_torrance_{key}"]),
            )
            for label, key in (
                ("RGB RMSE, calibration frames (levels)", "rgb_rmse_calibration"),
                ("RGB RMSE, test frames (levels)", "rgb_rmse_test"),
                ("SfS 3D error, mean (mm)", "sfs_error_mm"),
                ("SfS 3D error, median (mm)", "sfs_error_median_mm"),
                ("SfS 3D error near highlights, mean (mm)", "sfs_error_near_highlights_mm"),
            )
        ]
    )
    light = _table(
        [
            ("model", "RGB RMSE calibration", "RGB RMSE held-out", "noise floor"),
            (
                "near light",
                _fmt(near["rgb_rmse_calibration"]),
                _fmt(near["rgb_rmse_heldout"]),
                _fmt(near["noise_floor"]),
            ),
            (
                "light field (paper)",
                _fmt(field["rgb_rmse_calibration"]),
                _fmt(field["rgb_rmse_heldout"]),
                _fmt(field["noise_floor"]),
            ),
        ]
    )
    shape = _table(
        [
            ("registered frames", f"{len(sfm['registered'])}/{sfm['frames']}"),
            ("3D points", sfm["points"]),
            ("mean reprojection error (px)", _fmt(sfm["mean_reprojection_error_px"])),
            ("coverage", _fmt(sfm["coverage"])),
            ("normal error vs truth, median / p90 (deg)", _fmt(summary["sfm_normal_error_deg"])),
        ]
    )
    timings = _table([(k, f"{v:.1f} s") for k, v in summary["timings_s"].items()])
    images = "".join(
        f'<figure><img alt="{name}" src="data:image/png;base64,'
        f'{base64.b64encode(path.read_bytes()).decode()}"><figcaption>{_caption(name)}'
        "</figcaption></figure>"
        for name, path in figures.items()
    )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>ctjax demo</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin:0.5em 0}}td{{border:1px solid #ccc;padding:4px 8px}}
tr:first-child td{{font-weight:bold}}img{{max-width:100%}}</style></head><body>
<h1>ctjax demo: a synthetic laparoscope capture, from images alone</h1>
<p>{summary["frames"]} frames of {summary["size"]} were synthesised (textured tissue,
Cook-Torrance reflectance, light at the tip, 1 level of noise, 8 bits); only the images and
the camera's intrinsics went into the pipeline: structure-from-motion (pycolmap, its surfaces
refined by the texture seen from the other frames), the specular
set S and its ring S~, the paper's BRDF estimate (branch-and-bound over sigma), the light
(a near point light, and the paper's per-pixel light field) and the paper's evaluation of
Lambertian against Cook-Torrance.</p>
<p><b>What the ground truth is used for.</b> (1) The metric scale: structure-from-motion
recovers the shape up to scale, and the demo gives it the working distance
({_fmt(summary["scale_mm"])} mm, the median true depth of the first frame), as a user gives
a known size (the distance to the tissue, a tool's width); (2) scoring: the truth column
below and the reference depth of the shape-from-shading errors. Nothing else.</p>
<h2>Estimates used downstream, beside the truth</h2>{parameters}
<p>Every estimate has one albedo per surface point (the albedo map, from all frames):
rho_tilde is its median, the truth's the texture's base albedo. The near light is what the
evaluation uses.</p>
<h2>Warnings</h2>{warnings}
<h2>Shape from images (SfM)</h2>{shape}
<h2>Light</h2>{light}
<h2>Evaluation (paper section 7; calibration frames {ev["calibration_frames"]}, test frames
{ev["test_frames"]})</h2>{errors}
<p>Shape from shading, both against the ground-truth depth after scaling to its bounding-box
volume: Lambertian = Tsai-Shah (light at the tip); Cook-Torrance = the same formulation with
the estimated Cook-Torrance model and near light as the reflectance map, every pixel's RGB
linearised, solved jointly and coarse to fine. Both assume one albedo: the texture reads as
shading, which limits both here.</p>
<h2>Figures</h2>{images}
<h2>Timings</h2>{timings}
</body></html>
"""
    path = out / "report.html"
    path.write_text(page)
    return path


def _normal_error_deg(capture, truth) -> list[float]:
    """Median and 90th percentile (deg) of the reconstructed normals' error."""
    cosine = [
        np.sum(f.normals * t.normals, axis=-1)[f.geometry_mask]
        for f, t in zip(capture.frames, truth.frames, strict=True)
    ]
    angles = np.degrees(np.arccos(np.clip(np.concatenate(cosine), -1, 1)))
    return [round(float(np.median(angles)), 3), round(float(np.percentile(angles, 90)), 3)]


def _figures(out: Path, capture, truth, sets, near, field, evaluation) -> dict[str, Path]:
    figures_dir = out / "figures"
    figures_dir.mkdir(exist_ok=True)
    figures = {"inputs": _figure_inputs(capture, truth, sets, figures_dir / "inputs.png")}
    path = figures_dir / "light.png"
    figures["light"] = _figure_light(field, near.to_json(), capture, path)
    figures.update(evaluation_plots(capture, evaluation, figures_dir))
    return figures


# What the demo's summary keeps of the BRDF fit.
_FIT_KEYS = (
    "rho_tilde",
    "F_tilde",
    "sigma",
    "rgb_rmse",
    "albedo",
    "n_points",
    "n_ring_pixels",
    "status",
    "undetermined",
    "halves",
    "warnings",
)


def _truth(truth) -> dict:
    """The synthetic capture's true BRDF, light position and light field angle."""
    light = truth.truth.get("light", {}).get("position_mm", [0.0, 0.0, 0.0])
    return {
        **{k: truth.truth[k] for k in ("rho_tilde", "F_tilde", "sigma")},
        "light_mm": light,
        "field_angle_deg": _true_field_angle(truth, light),
    }


def run_demo(out: Path, options: SynthOptions | None = None, *, falloff: str = "auto") -> dict:
    """Run the whole pipeline into folder `out`; returns the summary (`out/summary.json`).
    `falloff`: the near light's falloff set by name (`named_falloff`; "auto": every set,
    chosen on held-out frames)."""
    if falloff not in FALLOFF_NAMES:  # before the minutes of work that precede its use
        raise CtjaxError(f"falloff must be one of {', '.join(FALLOFF_NAMES)}, got {falloff!r}")
    options = SynthOptions(texture_contrast=DEMO_TEXTURE_CONTRAST) if options is None else options
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    step = _Steps(_log)
    started = time.perf_counter()
    truth_dir = step(
        "synth",
        f"synthesising {options.frames} textured frames at {options.width}x{options.height}...",
        synthesize,
        out / "capture-truth",
        options,
    )
    truth = load_capture(truth_dir)
    images_dir = _images_only(truth_dir, out / "capture")
    # The known size that fixes SfM's scale: the working distance (median depth, frame 0).
    working_distance = float(np.nanmedian(truth.frames[0].depth[truth.frames[0].geometry_mask]))
    sfm = step(
        "reconstruct",
        "structure-from-motion on the images alone (pycolmap)...",
        reconstruct,
        images_dir,
        scale_mm=working_distance,
    )
    capture = load_capture(images_dir)
    masks = MaskOptions(ring_px=DEMO_RING_PX)
    sets = step("masks", "specular set S and ring S~...", capture_sets, capture, masks)
    fit = step(
        "fit",
        "BRDF (rho_tilde map, F_tilde, sigma) from all frames...",
        fit_capture,
        capture,
        masks,
    ).to_json()
    _log(
        f"  sigma {fit['sigma']:.4f} (truth {truth.truth['sigma']}), rho_tilde "
        f"{np.round(fit['rho_tilde'], 3).tolist()}, F_tilde {np.round(fit['F_tilde'], 3).tolist()}"
    )
    near = step(
        "calibrate_light_near",
        "near-light model (LM, all frames)...",
        calibrate_near_light,
        capture,
        falloff=named_falloff(falloff, capture),
        max_samples=8000,
        heldout_samples=20_000,
    )
    field = step(
        "calibrate_light_field",
        "the paper's per-pixel light field (LM per pixel, B-spline)...",
        calibrate_light_field,
        capture,
        brdf_rounds=1,
        solver=ClosedFormLM(iterations=10),
    )
    # Judged on the test frames, Cook-Torrance is fitted again on the calibration frames
    # alone (`near` above saw every frame: its falloff chosen on the last ones, its model
    # refitted on all of them), as the Lambertian model is.
    evaluation = step(
        "evaluate",
        "evaluation: Lambertian vs Cook-Torrance, RGB error and shape from shading...",
        evaluate,
        capture,
        cook_torrance=functools.partial(
            calibrate_near_light,
            falloff=named_falloff(falloff, capture),
            max_samples=8000,
            heldout_samples=20_000,
        ),
        reference=truth,
        progress=lambda m: _log(f"  {m}"),
    )
    figures = _figures(out, capture, truth, sets, near, field, evaluation)
    summary = {
        "capture": str(images_dir),
        "ground_truth": str(truth_dir),
        "frames": options.frames,
        "size": f"{options.width}x{options.height}",
        "truth": _truth(truth),
        "length_unit": "mm",
        "scale_mm": working_distance,
        "truth_used_for": [
            "the metric scale of the reconstruction: the working distance (median true "
            "depth of the first frame), as a user gives a known size",
            "scoring: the truth columns and the shape-from-shading reference depth",
        ],
        "reconstruction": sfm,
        "sfm_normal_error_deg": _normal_error_deg(capture, truth),
        "brdf_fit": {k: fit[k] for k in _FIT_KEYS if k in fit},
        "near_light": near.to_json(),
        "light_field": field.to_json(),
        "evaluation": evaluation.to_json(),
        "warnings": _warnings(fit, near, field, evaluation),
        "timings_s": {**step.seconds, "total": round(time.perf_counter() - started, 2)},
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=_json_default) + "\n")
    _write_report(out, summary, figures)
    _log(f"done in {summary['timings_s']['total']:.0f} s")
    return summary


def _json_default(value):
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
