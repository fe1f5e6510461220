"""Figures of a diagnosis: residual maps and binned residuals, before and after."""

from pathlib import Path

import numpy as np

from .._residuals import figure as _figure
from .._residuals import plot_residual_maps
from .._units import length_unit_of
from ..fitting import pixel_predict, predictions
from ..io import Capture
from ..observations import Observations
from ._variables import VARIABLES, binned, physical_variables, variable_label


def _map_residual(capture, frames, model, samples) -> np.ndarray:
    """(N, 3) model - measured at `samples` (8-bit levels) under the albedo map: each
    pixel's albedo fitted to the other frames that see it (`map_residuals`, as the residual
    maps and the held-out RMSE); NaN where no other frame does."""
    from ..estimation._dense_maps import map_residuals
    from ..fitting._map_least_squares import diffuse_lobe

    images = map_residuals(
        capture,
        model.brdf,
        model.light,
        list(frames),
        per_point=diffuse_lobe(model),
        effects=tuple(model.effects),
    )
    by_frame = dict(zip(frames, images, strict=True))
    frame, row, col = (np.asarray(a) for a in (samples.frame, samples.row, samples.col))
    out = np.full((len(frame), 3), np.nan)
    for index, image in by_frame.items():
        here = frame == index
        out[here] = -255 * image[row[here], col[here]]
    return out


def pixel_residuals(capture, frames, model, samples, albedo: str = "uniform") -> np.ndarray:
    """(N, 3) model - measured at `samples` (pixels of `frames`), 8-bit levels: under the
    map each pixel's albedo from the other frames that see it (NaN where none does);
    `"uniform"`: the model as it is."""
    if albedo == "map":
        return _map_residual(capture, frames, model, samples)
    predicted = np.asarray(predictions(model, samples, pixel_predict))
    return 255 * (predicted - np.asarray(samples.values))


def binned_residuals(capture, frames, model, samples, albedo: str = "uniform") -> dict:
    """For each variable of `VARIABLES`: (bin centres, mean residual (bins, 3) in 8-bit
    levels, model - measured) over `samples` (pixels of `frames`); `albedo` as in
    `plot_binned_residuals`. Samples without a residual (under the map: no other frame sees
    them) are left out."""
    residual = pixel_residuals(capture, frames, model, samples, albedo)
    variables = physical_variables(model, samples, capture.camera)
    known = np.all(np.isfinite(residual), axis=1)
    out = {}
    for name in VARIABLES:
        centres, means, _ = binned(np.asarray(variables[name])[known], residual[known])
        out[name] = (centres, means)
    return out


def plot_binned_residuals(
    capture, frames, models: dict, path: Path, max_samples=40_000, albedo: str = "uniform"
) -> Path:
    """Mean residual (model - measured) per channel against each physical variable, one
    curve per model. `albedo="map"`: the albedo-map model's residuals (each pixel's albedo
    from the other frames that see it: the model whose held-out RMSE the diagnosis
    reports); `"uniform"`: the model as it is, its one rho_tilde."""
    samples = Observations.of(capture).pixels(frames, max_samples=max_samples, seed=2)
    names = list(VARIABLES)
    columns = (len(names) + 1) // 2
    fig = _figure(figsize=(4 * columns, 6.5))
    axes = fig.subplots(2, columns)
    axes = axes.ravel()
    colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
    styles = ["-", "--", ":", "-."]
    for style, (label, model) in zip(styles, models.items(), strict=False):
        curves = binned_residuals(capture, frames, model, samples, albedo)
        for ax, name in zip(axes, names, strict=False):
            centres, means = curves[name]
            for c, channel in enumerate("RGB"):
                ax.plot(
                    centres,
                    means[:, c],
                    style,
                    color=colours[channel],
                    label=f"{label} {channel}" if name == names[0] else None,
                )
            ax.axhline(0, color="k", lw=0.5)
            ax.set_xlabel(variable_label(name, length_unit_of(capture)))
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
            capture,
            diagnosis.heldout_frames,
            models,
            out / "binned_residuals.png",
            albedo=diagnosis.base.details.get("albedo", "uniform"),
        ),
    ]
