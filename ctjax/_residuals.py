"""Residual maps: where a model and the measurements disagree, frame by frame.

Below calibration, evaluation and diagnostics, which all draw them.
"""

from pathlib import Path

import numpy as np

from .io import Capture
from .observations import usable_mask


def figure(**kwargs):
    # A bare Figure, not pyplot: no global backend switch (notebooks keep their inline
    # display) and nothing left open.
    from matplotlib.figure import Figure

    return Figure(layout="constrained", **kwargs)


def residual_map(capture: Capture, index: int, model, albedo: str = "uniform") -> np.ndarray:
    """Mean-RGB residual (model - image) of one frame in 8-bit levels; NaN where unusable.

    `albedo="uniform"`: the model as it is (its one rho_tilde); `"map"`: the albedo-map
    model whose errors the estimators report, each pixel's albedo fitted to the other frames
    that see it (`ctjax.estimation._dense_maps.map_residuals`; NaN where none does), so
    that the texture is not drawn as the model's error."""
    frame = capture.frames[index]
    if albedo == "map":
        from .estimation._dense_maps import map_residuals
        from .fitting._map_least_squares import diffuse_lobe

        (measured_minus_model,) = map_residuals(
            capture,
            model.brdf,
            model.light,
            [index],
            per_point=diffuse_lobe(model),
            effects=tuple(model.effects),
        )
        return -measured_minus_model.mean(axis=-1) * 255
    rendered = np.asarray(model.render(capture.camera, frame.normals, frame.depth, index))
    residual = (rendered - frame.image).mean(axis=-1) * 255
    return np.where(usable_mask(frame, np.asarray(capture.saturation)), residual, np.nan)


def display(image: np.ndarray, encoding: str = "srgb") -> np.ndarray:
    """A linear image as a screen shows it: sRGB-encoded, in [0, 1]."""
    from .io._encoding import linear_to_srgb

    image = np.clip(image, 0, 1)
    return linear_to_srgb(image) if encoding == "srgb" else image


def plot_residual_maps(capture, index, models: dict, path: Path, albedo="uniform") -> Path:
    """The frame and each model's `residual_map` beside it (`albedo` as there)."""
    fig = figure(figsize=(4.2 * (len(models) + 1), 3.4))
    axes = fig.subplots(1, len(models) + 1)
    axes[0].imshow(display(capture.frames[index].image))
    axes[0].set_title(f"held-out frame {capture.frames[index].name}")
    maps = {name: residual_map(capture, index, m, albedo) for name, m in models.items()}
    limit = max(
        3.0, float(np.nanpercentile(np.abs(np.concatenate([m.ravel() for m in maps.values()])), 99))
    )
    for ax, (name, data) in zip(axes[1:], maps.items(), strict=True):
        shown = ax.imshow(data, cmap="RdBu_r", vmin=-limit, vmax=limit)
        rmse = np.sqrt(np.nanmean(data**2))
        where = ", albedo map" if albedo == "map" else ""
        ax.set_title(f"{name}: residual (levels{where}), RMS {rmse:.2f}", fontsize=9)
        fig.colorbar(shown, ax=ax, shrink=0.8)
    for ax in axes:
        ax.set_axis_off()
    fig.savefig(path, dpi=80)
    return path
