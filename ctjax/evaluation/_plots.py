"""The paper's figures for an evaluation: RGB and 3D error bars (Fig. 4/6), SfS side by side
(Fig. 5/7), and error maps. matplotlib's object API (no pyplot state)."""

from pathlib import Path

import numpy as np

from .._residuals import plot_residual_maps
from .._units import METRIC, label, length_unit_of
from ..io import Capture

_COLOURS = {"lambertian": "#9e9e9e", "cook_torrance": "#c0392b"}
_LABELS = {"lambertian": "Lambertian", "cook_torrance": "Cook-Torrance"}


def _figure(**kwargs):
    from matplotlib.figure import Figure

    return Figure(layout="constrained", **kwargs)


def plot_error_bars(evaluation, path: Path, unit: str = METRIC) -> Path:
    """Fig. 4/6: RGB error on calibration and test frames, and SfS 3D error, per model;
    `unit` the capture's length unit (`ctjax._units`), the depth errors' on the axis."""
    summary = evaluation.to_json()
    fig = _figure(figsize=(10, 3.6))
    left, right = fig.subplots(1, 2)
    width = 0.38
    for k, model in enumerate(("lambertian", "cook_torrance")):
        values = [summary[f"{model}_rgb_rmse_calibration"], summary[f"{model}_rgb_rmse_test"]]
        bars = left.bar(
            np.arange(2) + (k - 0.5) * width,
            values,
            width,
            color=_COLOURS[model],
            label=_LABELS[model],
        )
        left.bar_label(bars, fmt="%.2f", fontsize=8)
        errors = [
            summary[f"{model}_sfs_error_mm"],
            summary[f"{model}_sfs_error_median_mm"],
            summary[f"{model}_sfs_error_near_highlights_mm"],
        ]
        errors = [np.nan if e is None else e for e in errors]
        bars = right.bar(np.arange(3) + (k - 0.5) * width, errors, width, color=_COLOURS[model])
        right.bar_label(bars, fmt="%.2f", fontsize=8)
    left.set_xticks(range(2), ["calibration frames", "test frames"])
    left.set_ylabel("RGB RMSE (8-bit levels)")
    left.set_title("RGB error")
    left.legend(loc="lower right")
    right.set_xticks(range(3), ["mean", "median", "mean near highlights"])
    right.set_ylabel(f"|depth error| ({label(unit)})")
    right.set_title("shape from shading, test frames")
    fig.savefig(path, dpi=90)
    return path


def plot_shapes(shape, path: Path, unit: str = METRIC) -> Path:
    """Fig. 5/7: the image, the reference depth, SfS Lambertian and SfS Cook-Torrance, and
    the two SfS error maps, one test frame; depths in `unit`, the capture's length unit."""
    shown_unit = label(unit)
    fig = _figure(figsize=(15, 6.2))
    axes = fig.subplots(2, 4)
    depths = [shape.reference, shape.lambertian.depth, shape.cook_torrance.depth]
    low = np.nanpercentile(np.concatenate([d[shape.mask] for d in depths]), 1)
    high = np.nanpercentile(np.concatenate([d[shape.mask] for d in depths]), 99)
    axes[0, 0].imshow(np.clip(shape.image, 0, 1))
    axes[0, 0].set_title(f"image ({shape.name})")
    for ax, depth, title in zip(
        axes[0, 1:],
        depths,
        ("reference depth", "SfS Lambertian (Tsai-Shah)", "SfS Cook-Torrance"),
        strict=True,
    ):
        shown = ax.imshow(np.where(shape.mask, depth, np.nan), cmap="viridis", vmin=low, vmax=high)
        ax.set_title(f"{title} ({shown_unit})")
        fig.colorbar(shown, ax=ax, shrink=0.8)
    errors = [np.abs(d - shape.reference) for d in depths[1:]]
    limit = np.nanpercentile(np.concatenate([e[shape.mask] for e in errors]), 98)
    axes[1, 0].imshow(np.where(shape.near_highlight, 1.0, np.nan), cmap="Reds", vmin=0, vmax=1)
    axes[1, 0].set_title("near highlights (S dilated)")
    for ax, error, title in zip(axes[1, 1:3], errors, ("Lambertian", "Cook-Torrance"), strict=True):
        shown = ax.imshow(np.where(shape.mask, error, np.nan), cmap="magma", vmin=0, vmax=limit)
        ax.set_title(f"|depth error|, {title} ({shown_unit})")
        fig.colorbar(shown, ax=ax, shrink=0.8)
    difference = errors[0] - errors[1]
    bound = np.nanpercentile(np.abs(difference[shape.mask]), 98) or 1.0
    shown = axes[1, 3].imshow(
        np.where(shape.mask, difference, np.nan), cmap="RdBu", vmin=-bound, vmax=bound
    )
    axes[1, 3].set_title(f"Lambertian error - Cook-Torrance error ({shown_unit})")
    fig.colorbar(shown, ax=axes[1, 3], shrink=0.8)
    for ax in axes.ravel():
        ax.set_axis_off()
    fig.savefig(path, dpi=80)
    return path


def plot_rgb_residuals(capture: Capture, evaluation, path: Path) -> Path:
    """RGB residual maps of both models on the first test frame (diagnostics' figure), and
    of the Lambertian model under Cook-Torrance's light where it was fitted; under the
    albedo map when the errors beside them are the map's."""
    models = {_LABELS[m]: getattr(evaluation, m).model for m in ("lambertian", "cook_torrance")}
    if evaluation.lambertian_same_light is not None:
        models = {
            _LABELS["lambertian"]: evaluation.lambertian.model,
            "Lambertian, same light": evaluation.lambertian_same_light.model,
            _LABELS["cook_torrance"]: evaluation.cook_torrance.model,
        }
    index = evaluation.test_frames[0]
    return plot_residual_maps(capture, index, models, path, albedo=evaluation.albedo)


def evaluation_plots(capture: Capture, evaluation, out: Path) -> dict[str, Path]:
    """Every figure of an evaluation into folder `out`; returns {name: path}."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    unit = length_unit_of(capture)
    paths = {"error_bars": plot_error_bars(evaluation, out / "errors.png", unit)}
    paths["rgb_residuals"] = plot_rgb_residuals(capture, evaluation, out / "rgb_residuals.png")
    for shape in evaluation.shapes[:2]:
        paths[f"sfs_{shape.name}"] = plot_shapes(shape, out / f"sfs_{shape.name}.png", unit)
    return paths
