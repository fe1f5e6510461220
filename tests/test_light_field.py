"""The paper's per-pixel light field (eq. 7-8): directions against the known light."""

import json

import numpy as np
import pytest

from ctjax._errors import CtjaxError
from ctjax._geometry import points_from_depth
from ctjax.calibration import calibrate_light_field
from ctjax.calibration._light_field import directions_from_paper_angles, paper_angles
from ctjax.cli import main
from ctjax.io import load_capture
from ctjax.synth import SynthOptions, synthesize

SMALL = dict(width=128, height=96, frames=4, texture=False, seed=5)
OFFSET_MM = (6.0, 0.0, 0.0)


def true_directions(capture, frame: int = 0) -> np.ndarray:
    """Unit vectors from the GT surface point to the light, camera frame (H, W, 3).

    For a light offset from the lens they depend on depth, so on the frame: compared on the
    reference (first) frame, whose pixels the calibration also uses.
    """
    point = points_from_depth(capture.camera, capture.frames[frame].depth)
    to_light = np.asarray(OFFSET_MM) - point
    return to_light / np.linalg.norm(to_light, axis=-1, keepdims=True)


def median_angle_deg(directions, truth) -> float:
    ok = np.all(np.isfinite(truth), axis=-1)
    cosine = np.clip(np.sum(directions[ok] * truth[ok], axis=-1), -1, 1)
    return float(np.median(np.degrees(np.arccos(cosine))))


@pytest.fixture(scope="module")
def offset_capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("field") / "capture"
    return synthesize(root, SynthOptions(**SMALL, light_offset_mm=OFFSET_MM))


def test_paper_angles_round_trip():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(50, 3))
    directions[:, 2] = -np.abs(directions[:, 2])  # towards the camera
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    theta, phi = paper_angles(directions)
    assert np.all(phi < np.pi / 2)  # eq. (7)'s range for lights in front of the surface
    np.testing.assert_allclose(directions_from_paper_angles(theta, phi), directions, atol=1e-12)


def test_calibrate_light_field_command(offset_capture, tmp_path):
    out, npz = tmp_path / "field.json", tmp_path / "field.npz"
    argv = ["calibrate-light", str(offset_capture), "--model", "field"]
    assert main([*argv, "--json", str(out), "--npz", str(npz)]) == 0
    summary = json.loads(out.read_text())
    arrays = np.load(npz)
    directions = arrays["directions"]
    assert directions.shape == (SMALL["height"], SMALL["width"], 3)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=-1), 1, atol=1e-5)
    truth = true_directions(load_capture(offset_capture))
    error = median_angle_deg(directions, truth)
    assert error <= 3.0, error
    # The field explains the images far better than the co-located light it starts from.
    assert summary["rgb_rmse_heldout"] < 0.5 * summary["rgb_rmse_heldout_colocated"]
    assert summary["rgb_rmse_heldout"] <= 1.5 * summary["noise_floor"]
    counts = summary["solver_status"]
    assert counts["converged"] >= 0.95 * summary["solved_pixels"]
    assert summary["settings"]["falloff"] == "none"
    for key in ("theta", "phi", "solved", "status"):
        assert arrays[key].shape == directions.shape[:2]
    assert np.all(arrays["status"][~arrays["solved"]] == -1)


def test_light_field_with_inverse_square_falloff(tmp_path):
    options = SynthOptions(**SMALL, light_offset_mm=OFFSET_MM, inverse_square=True)
    capture = load_capture(synthesize(tmp_path / "c", options))
    result = calibrate_light_field(capture, brdf_rounds=2)
    assert result.settings["falloff"] == "inverse_square"
    error = median_angle_deg(result.directions, true_directions(capture))
    assert error <= 3.0, error


def test_light_field_needs_a_highlight(tmp_path):
    options = SynthOptions(width=48, height=32, frames=2, texture=False, F_tilde=(0, 0, 0))
    capture = load_capture(synthesize(tmp_path / "c", options))
    with pytest.raises(CtjaxError, match="no specular pixels"):
        calibrate_light_field(capture)
