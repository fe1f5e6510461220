"""Lengths in a capture's unit: millimetres where depth is metric, median depths where the
shape was reconstructed without a known size (no key then ends in `_mm`)."""

import json

import numpy as np
import pytest

from ctjax._units import in_length_unit
from ctjax.cli import main
from ctjax.io import load_capture, write_capture
from ctjax.synth import SynthOptions, synthesize


def _keys(tree):
    if isinstance(tree, dict):
        for key, value in tree.items():
            yield key
            yield from _keys(value)
    elif isinstance(tree, list):
        for value in tree:
            yield from _keys(value)


def test_a_relative_unit_renames_every_length_key():
    data = {"offset_mm": [1, 2, 3], "model": {"light": {"position_mm": [0, 0, 0]}}, "n": 3}
    assert in_length_unit(data, "mm") == {"length_unit": "mm", **data}
    relative = in_length_unit(data, "median_depth")
    assert relative["length_unit"] == "median_depth" and relative["offset"] == [1, 2, 3]
    assert relative["model"]["light"]["position"] == [0, 0, 0]
    assert not [k for k in _keys(relative) if k.endswith("_mm")]


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """The same small capture in millimetres, and up to scale (depth and poses divided by
    the median depth, and a reconstruction report that says it is not metric)."""
    root = tmp_path_factory.mktemp("units")
    metric = load_capture(
        synthesize(root / "mm", SynthOptions(width=96, height=72, frames=3, texture=False))
    )
    unit = float(np.nanmedian(metric.frames[0].depth))
    frames = []
    for frame in metric.frames:
        pose = frame.pose.copy()
        pose[:3, 3] /= unit
        frames.append(
            frame.__class__(frame.name, frame.image, frame.depth / unit, frame.normals, pose)
        )
    relative = write_capture(root / "relative", metric.camera, frames)
    report = {"scale": {"metric": False, "unit": "median reference depth (up to scale)"}}
    (relative / "reconstruction.json").write_text(json.dumps(report))
    return metric.root, relative


@pytest.mark.slow
def test_the_near_light_says_its_unit(captures, tmp_path):
    metric, relative = captures
    assert load_capture(metric).length_unit == "mm"
    assert load_capture(relative).length_unit == "median_depth"
    for capture, unit in ((metric, "mm"), (relative, "median_depth")):
        out = tmp_path / f"{unit}.json"
        argv = ["calibrate-light", str(capture), "--model", "near", "--albedo", "uniform"]
        assert main([*argv, "--falloff", "none", "--json", str(out)]) == 0
        result = json.loads(out.read_text())
        assert result["length_unit"] == unit
        lengths = [k for k in _keys(result) if k.endswith("_mm")]
        assert (unit == "mm") == bool(lengths), lengths
    # The same fit in either unit: the offsets agree once divided by the depth.
    offset_mm = json.loads((tmp_path / "mm.json").read_text())["offset_mm"]
    offset = json.loads((tmp_path / "median_depth.json").read_text())["offset"]
    depth = float(np.nanmedian(load_capture(metric).frames[0].depth))
    assert np.linalg.norm(np.asarray(offset_mm) / depth - np.asarray(offset)) < 0.01


def test_the_figures_name_lengths_in_the_captures_unit(tmp_path, monkeypatch):
    """The evaluation's figures (Fig. 4-7) label depths and depth errors "mm" only where the
    capture is metric: a shape reconstructed up to scale is in median depths."""
    from types import SimpleNamespace

    from matplotlib.figure import Figure

    from ctjax.evaluation._plots import plot_error_bars, plot_shapes

    drawn = []
    monkeypatch.setattr(Figure, "savefig", lambda figure, *a, **k: drawn.append(figure))
    summary = {
        f"{model}_{key}": 1.0
        for model in ("lambertian", "cook_torrance")
        for key in (
            "rgb_rmse_calibration",
            "rgb_rmse_test",
            "sfs_error_mm",
            "sfs_error_median_mm",
            "sfs_error_near_highlights_mm",
        )
    }
    evaluation = SimpleNamespace(to_json=lambda: summary)
    depth = np.linspace(1.0, 2.0, 64).reshape(8, 8)
    shape = SimpleNamespace(
        name="f",
        image=np.full((8, 8, 3), 0.5),
        mask=np.ones((8, 8), bool),
        near_highlight=np.zeros((8, 8), bool),
        reference=depth,
        lambertian=SimpleNamespace(depth=depth + 0.1),
        cook_torrance=SimpleNamespace(depth=depth - 0.1),
    )

    def labels(figure):
        return " ".join(a.get_title() + " " + a.get_ylabel() for a in figure.axes)

    for unit, shown in (("mm", "(mm)"), ("median_depth", "(median depths (up to scale))")):
        drawn.clear()
        plot_error_bars(evaluation, tmp_path / "bars.png", unit)
        plot_shapes(shape, tmp_path / "shapes.png", unit)
        bars, shapes = (labels(figure) for figure in drawn)
        assert f"|depth error| {shown}" in bars
        assert f"reference depth {shown}" in shapes
        assert f"Cook-Torrance error {shown}" in shapes
        assert unit == "mm" or "(mm)" not in bars + shapes
