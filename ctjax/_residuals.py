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


def residual_map(capture: Capture, index: int, model) -> np.ndarray:
    """Mean-RGB residual (model - image) of one frame in 8-bit levels; NaN where unusable."""
    frame = capture.frames[index]
    rendered = np.asarray(model.render(capture.camera, frame.normals, frame.depth))
    residual = (rendered - frame.image).mean(axis=-1) * 255
    return np.where(usable_mask(frame), residual, np.nan)


def plot_residual_maps(capture, index, models: dict, path: Path) -> Path:
    fig = figure(figsize=(4.2 * (len(models) + 1), 3.4))
    axes = fig.subplots(1, len(models) + 1)
    axes[0].imshow(np.clip(capture.frames[index].image, 0, 1))
    axes[0].set_title(f"held-out frame {capture.frames[index].name}")
    maps = {name: residual_map(capture, index, m) for name, m in models.items()}
    limit = max(
        3.0, float(np.nanpercentile(np.abs(np.concatenate([m.ravel() for m in maps.values()])), 99))
    )
    for ax, (name, data) in zip(axes[1:], maps.items(), strict=True):
        shown = ax.imshow(data, cmap="RdBu_r", vmin=-limit, vmax=limit)
        rmse = np.sqrt(np.nanmean(data**2))
        ax.set_title(f"{name}: residual (levels), RMS {rmse:.2f}")
        fig.colorbar(shown, ax=ax, shrink=0.8)
    for ax in axes:
        ax.set_axis_off()
    fig.savefig(path, dpi=80)
    return path
