"""The near-light model: a point light offset from the lens, with or without falloff."""

import json

import numpy as np
import pytest

from ctjax.calibration import calibrate_near_light
from ctjax.cli import main
from ctjax.io import load_capture
from ctjax.synth import SynthOptions, synthesize

SMALL = dict(width=112, height=88, frames=5, texture=False, seed=5)
NOISE_FLOOR = np.sqrt(1 + 1 / 12)  # 1 level of noise and 8-bit quantisation


def test_near_light_recovers_the_offset_and_needs_no_falloff(tmp_path):
    options = SynthOptions(**SMALL, effects={"light_offset": (6.0, -2.0, 0.0)})
    capture = load_capture(synthesize(tmp_path / "c", options))
    # The paper's one albedo (the capture is untextured; the map is tested below).
    result = calibrate_near_light(
        capture, max_samples=8000, heldout_samples=20_000, albedo="uniform"
    )
    np.testing.assert_allclose(np.asarray(result.model.light.position_mm), [6, -2, 0], atol=1.0)
    # Falloffs the data do not show are not chosen (the simplest model within 1%).
    assert result.model.light.falloff == ()
    assert result.details["falloff"] == {}
    selection = result.details["falloff_selection"]
    assert set(selection) == {"none", "inverse_square", "spot", "inverse_square+spot"}
    assert result.heldout_rmse <= 1.15 * NOISE_FLOOR
    assert result.noise_floor == pytest.approx(NOISE_FLOOR, rel=0.1)


def test_calibrate_light_command_with_falloffs(tmp_path, capsys, coarse_facets):
    options = SynthOptions(
        **SMALL,
        effects={"light_offset": (-3.0, 7.0, 1.0), "inverse_square": True, "spot_falloff": 3.0},
    )
    root = synthesize(tmp_path / "c", options)
    out = tmp_path / "light.json"
    argv = ["calibrate-light", str(root), "--model", "near", "--json", str(out)]
    assert main([*argv, "--falloff", "inverse_square+spot", "--facets"]) == 0
    result = json.loads(out.read_text())
    # The lobe about every point's own facet under the fitted light (tests/test_facets.py).
    assert result["facets"]["sigma"] > 0 and np.isfinite(result["facets"]["ratio"])
    assert "a lobe about every point's own facet" in capsys.readouterr().out
    assert main([*argv[:-2], "--model", "field", "--json", str(out), "--facets"]) == 2
    assert "--facets is for the near light" in capsys.readouterr().err
    np.testing.assert_allclose(result["offset_mm"], [-3.0, 7.0, 1.0], atol=1.0)
    assert set(result["falloff"]) == {"inverse_square", "spot"}
    assert result["falloff"]["spot"]["exponent"] == pytest.approx(3.0, rel=0.1)
    assert result["status"] == "successful"
    assert result["rgb_rmse_heldout"] <= 1.15 * NOISE_FLOOR
    # The highlights' alignment under the fitted light: never misoriented about true normals.
    assert result["highlight_alignment"]["status"] in ("aligned", "too_few_highlights")


@pytest.fixture(scope="module")
def independent_near(tmp_path_factory):
    """Textured captures from tests/independent.py (no ctjax code), 160x128, 6 frames:
    light offset (6, -4, 0) mm with inverse-square falloff, and light at the lens."""
    from independent import Scene, render_capture

    scenes = {
        "offset": Scene(light_offset_mm=(6.0, -4.0, 0.0), inverse_square_mm=68.0),
        "lens": Scene(),
    }
    roots = {}
    for name, scene in scenes.items():
        roots[name] = tmp_path_factory.mktemp(name)
        render_capture(roots[name], 160, 128, 6, seed=1, scene=scene, normals=False)
    return scenes, roots


def test_near_light_with_the_albedo_map_finds_the_offset(independent_near):
    from ctjax.lights import InverseSquare

    scenes, roots = independent_near
    capture = load_capture(roots["offset"])
    result = calibrate_near_light(capture, falloff=(InverseSquare(68.0),), max_samples=4000)
    fit = result.to_json()
    assert fit["albedo"] == "map" and fit["offset_detected"]
    np.testing.assert_allclose(fit["offset_mm"], [6.0, -4.0, 0.0], atol=0.5)
    assert fit["sigma"] == pytest.approx(scenes["offset"].sigma, rel=0.01)
    # Chosen on the held-out frames, the model's parameters come from every frame's points.
    assert "every frame" in fit["parameters_from"]
    assert result.rmse["all_frames"] < 1.3
    # The standard error is small and says so; the light at the lens is far worse.
    assert np.all(np.asarray(fit["offset_stderr_mm"]) < 0.2)
    assert fit["lens_heldout_rmse"] > 1.5 * fit["rgb_rmse_heldout"]
    assert result.heldout_rmse < 1.3 and result.noise_floor == pytest.approx(1.0, abs=0.2)


def test_near_light_with_the_albedo_map_reports_no_offset_at_the_lens(independent_near):
    scenes, roots = independent_near
    capture = load_capture(roots["lens"])
    result = calibrate_near_light(capture, falloff=(), max_samples=4000)
    fit = result.to_json()
    assert not fit["offset_detected"] and fit["offset_mm"] == [0.0, 0.0, 0.0]
    assert 0 < fit["offset_bound_mm"] < 0.5
    assert any("no light offset detected" in w for w in result.warnings)
    assert fit["sigma"] == pytest.approx(scenes["lens"].sigma, rel=0.01)
    # The paper's uniform albedo on the same textured capture: a spurious offset or a bad fit.
    uniform = calibrate_near_light(capture, falloff=(), albedo="uniform")
    assert uniform.heldout_rmse > 2 * result.heldout_rmse
