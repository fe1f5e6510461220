"""Shape from rigid SfM (`ctjax reconstruct`, `ctjax.sfm`) against synthetic ground truth.

One textured capture (320x256, 5 frames) is reconstructed once, from a copy holding only its
images and camera.json, through the command line; the tests compare with the original's
depth and normals.
"""

import json
import shutil

import cv2
import numpy as np
import pytest

from ctjax import CaptureError, ParameterError, ReconstructionError
from ctjax.cli import main
from ctjax.io import load_capture
from ctjax.sfm import reconstruct, reconstruct_capture
from ctjax.synth import SynthOptions, synthesize


def _images_only(capture, out):
    out.mkdir()
    shutil.copy(capture / "camera.json", out / "camera.json")
    shutil.copytree(capture / "images", out / "images")
    return out


@pytest.fixture(scope="module")
def reconstructed(tmp_path_factory):
    root = tmp_path_factory.mktemp("sfm")
    truth = synthesize(root / "truth", SynthOptions(width=320, height=256, frames=5, seed=1))
    images = _images_only(truth, root / "images-only")
    # A known working distance: the true median depth of the first frame.
    scale_mm = float(np.nanmedian(np.load(truth / "depth" / "frame_000.npy")))
    status = main(
        [
            "reconstruct",
            str(images),
            "--scale-mm",
            str(scale_mm),
            "--json",
            str(root / "report.json"),
        ]
    )
    assert status == 0
    report = json.loads((root / "report.json").read_text())
    return load_capture(truth), load_capture(images), report


def _angles(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


def test_every_frame_registers_with_small_reprojection_error(reconstructed):
    truth, _, report = reconstructed
    assert report["registered"] == [f.name for f in truth.frames]
    assert report["unregistered"] == []
    assert report["points"] > 1000
    assert report["mean_reprojection_error_px"] < 0.5
    assert report["coverage"] > 0.8
    assert report["scale"]["metric"] and report["scale"]["unit"] == "mm"


def test_normals_match_ground_truth_inside_the_hull(reconstructed):
    truth, estimate, _ = reconstructed
    errors = []
    for true_frame, frame in zip(truth.frames, estimate.frames, strict=True):
        covered = frame.geometry_mask & true_frame.geometry_mask
        assert covered.mean() > 0.8
        errors.append(_angles(frame.normals[covered], true_frame.normals[covered]))
    errors = np.concatenate(errors)
    assert np.median(errors) <= 3.0
    assert np.percentile(errors, 90) <= 10.0


def test_metric_depth_and_poses_with_a_known_distance(reconstructed):
    truth, estimate, report = reconstructed
    assert report["length_unit"] == "mm" and estimate.length_unit == "mm"
    for true_frame, frame in zip(truth.frames, estimate.frames, strict=True):
        ok = frame.geometry_mask & true_frame.geometry_mask
        relative = np.abs(frame.depth[ok] - true_frame.depth[ok]) / true_frame.depth[ok]
        assert np.median(relative) < 0.03
    # Poses: the first frame is the world; baselines agree with the truth's in mm.
    np.testing.assert_allclose(estimate.frames[0].pose, np.eye(4), atol=1e-9)
    true_ref = np.linalg.inv(truth.frames[0].pose)
    for true_frame, frame in zip(truth.frames[1:], estimate.frames[1:], strict=True):
        true_centre = (true_ref @ true_frame.pose)[:3, 3]
        assert np.linalg.norm(frame.pose[:3, 3] - true_centre) < 0.1 * np.linalg.norm(true_centre)


def test_existing_geometry_is_not_overwritten_without_force(reconstructed, tmp_path):
    truth, _, _ = reconstructed
    before = (truth.root / "poses.json").read_bytes()
    with pytest.raises(CaptureError, match=r"poses\.json: exists"):
        reconstruct(truth.root)
    assert (truth.root / "poses.json").read_bytes() == before
    # A separate output folder is checked the same way.
    (tmp_path / "out" / "depth").mkdir(parents=True)
    (tmp_path / "out" / "depth" / "frame_002.npy").write_bytes(b"mine")
    with pytest.raises(CaptureError, match=r"frame_002\.npy: exists"):
        reconstruct(truth.root, tmp_path / "out")
    assert (tmp_path / "out" / "depth" / "frame_002.npy").read_bytes() == b"mine"


def test_scale_arguments_are_checked(reconstructed):
    truth, _, _ = reconstructed
    with pytest.raises(ParameterError, match="not both"):
        reconstruct(truth.root, scale_mm=70.0, volume_mm3=1e4)
    with pytest.raises(ParameterError, match="scale_mm"):
        reconstruct(truth.root, scale_mm=-1.0)


def test_untextured_images_fail_with_one_clear_line(tmp_path, capsys):
    capture = synthesize(
        tmp_path / "flat", SynthOptions(width=128, height=96, frames=3, texture=False)
    )
    with pytest.raises(ReconstructionError, match="too few features"):
        reconstruct_capture(load_capture(capture))
    assert main(["reconstruct", str(capture), "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("ctjax reconstruct: error: too few features")


def test_a_frame_that_does_not_register_is_reported_and_skipped(tmp_path):
    capture = synthesize(tmp_path / "c", SynthOptions(width=192, height=160, frames=3, seed=2))
    capture = _images_only(capture, tmp_path / "images-only")
    # An unrelated image (another texture altogether): features, but no match.
    noise = np.random.default_rng(0).integers(0, 256, (160, 192, 3), np.uint8)
    cv2.imwrite(str(capture / "images" / "frame_999.png"), cv2.GaussianBlur(noise, (3, 3), 0))
    report = reconstruct(capture)
    assert report["unregistered"] == ["frame_999"]
    assert report["registered"] == ["frame_000", "frame_001", "frame_002"]
    assert any("frame_999 did not register" in w for w in report["warnings"])
    assert not report["scale"]["metric"]
    assert not (capture / "depth" / "frame_999.npy").exists()
    assert (capture / "normals" / "frame_002.npy").is_file()


def test_little_parallax_is_named():
    from types import SimpleNamespace

    from ctjax.sfm._reconstruct import MIN_BASELINE, _baseline

    def view(x):
        pose = np.eye(4)
        pose[0, 3] = x
        return SimpleNamespace(pose=pose)

    scale = {"median_reference_depth": 1.0, "factor": 60.0}
    assert _baseline({"a": view(0.0), "b": view(0.6)}, scale) == pytest.approx(0.01)
    assert _baseline({"a": view(0.0), "b": view(0.6)}, scale) < MIN_BASELINE
    assert _baseline({"a": view(0.0)}, scale) is None
