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
    # The demo's sample counts: the compiled fits are shared with its test.
    result = calibrate_near_light(capture, max_samples=8000, heldout_samples=20_000)
    np.testing.assert_allclose(np.asarray(result.model.light.position_mm), [6, -2, 0], atol=1.0)
    # Falloffs the data do not show are not chosen (the simplest model within 1%).
    assert result.model.light.falloff == ()
    assert result.details["falloff"] == {}
    selection = result.details["falloff_selection"]
    assert set(selection) == {"none", "inverse_square", "spot", "inverse_square+spot"}
    assert result.heldout_rmse <= 1.15 * NOISE_FLOOR
    assert result.noise_floor == pytest.approx(NOISE_FLOOR, rel=0.1)


def test_calibrate_light_command_with_falloffs(tmp_path):
    options = SynthOptions(
        **SMALL,
        effects={"light_offset": (-3.0, 7.0, 1.0), "inverse_square": True, "spot_falloff": 3.0},
    )
    root = synthesize(tmp_path / "c", options)
    out = tmp_path / "light.json"
    argv = ["calibrate-light", str(root), "--model", "near", "--json", str(out)]
    assert main([*argv, "--falloff", "inverse_square+spot"]) == 0
    result = json.loads(out.read_text())
    np.testing.assert_allclose(result["offset_mm"], [-3.0, 7.0, 1.0], atol=1.0)
    assert set(result["falloff"]) == {"inverse_square", "spot"}
    assert result["falloff"]["spot"]["exponent"] == pytest.approx(3.0, rel=0.1)
    assert result["status"] == "successful"
    assert result["rgb_rmse_heldout"] <= 1.15 * NOISE_FLOOR
