"""Figures of a diagnosis: residual maps and binned residuals, before and after."""

from pathlib import Path

import numpy as np

from .._residuals import figure as _figure
from .._residuals import plot_residual_maps
from ..fitting import pixel_predict, predictions
from ..io import Capture
from ..observations import Observations
from ._variables import VARIABLES, binned, physical_variables


def plot_binned_residuals(capture, frames, models: dict, path: Path, max_samples=40_000) -> Path:
    """Mean residual per channel against each physical variable, one curve per model."""
    samples = Observations.of(capture).pixels(frames, max_samples=max_samples, seed=2)
    names = list(VARIABLES)
    columns = (len(names) + 1) // 2
    fig = _figure(figsize=(4 * columns, 6.5))
    axes = fig.subplots(2, columns)
    axes = axes.ravel()
    colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
    styles = ["-", "--", ":", "-."]
    for style, (label, model) in zip(styles, models.items(), strict=False):
        residual = 255 * (
            np.asarray(predictions(model, samples, pixel_predict)) - np.asarray(samples.values)
        )
        variables = physical_variables(model, samples, capture.camera)
        for ax, name in zip(axes, names, strict=False):
            centres, means, _ = binned(np.asarray(variables[name]), residual)
            for c, channel in enumerate("RGB"):
                ax.plot(
                    centres,
                    means[:, c],
                    style,
                    color=colours[channel],
                    label=f"{label} {channel}" if name == names[0] else None,
                )
            ax.axhline(0, color="k", lw=0.5)
            ax.set_xlabel(VARIABLES[name])
            ax.set_ylabel("mean residual (levels)")
    for ax in axes[len(names) :]:
        ax.set_axis_off()
    fig.legend(loc="lower right", fontsize=8)
    fig.savefig(path, dpi=80)
    return path


def diagnosis_plots(capture: Capture, diagnosis, out: Path) -> list[Path]:
    """Residual maps and binned residuals of the base model and of the verdict's model."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    models = {"base": diagnosis.base.model}
    if diagnosis.verdict != "none":
        models[f"+ {diagnosis.verdict}"] = diagnosis.best_model
    index = diagnosis.heldout_frames[0]
    return [
        plot_residual_maps(
            capture,
            index,
            models,
            out / "residual_maps.png",
            albedo=diagnosis.base.details.get("albedo", "uniform"),
        ),
        plot_binned_residuals(
            capture, diagnosis.heldout_frames, models, out / "binned_residuals.png"
        ),
    ]
