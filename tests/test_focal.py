"""`reconstruct --focal refine`: the focal length of an uncalibrated camera from the frames."""

import json
import shutil

import pytest

from ctjax._errors import CaptureError
from ctjax.cli import main
from ctjax.sfm import _focal, reconstruct
from ctjax.synth import SynthOptions, synthesize


@pytest.fixture(scope="module")
def guessed(tmp_path_factory):
    """A capture's images with the focal length guessed 20% short, and the true one."""
    root = tmp_path_factory.mktemp("focal")
    options = SynthOptions(width=192, height=160, frames=4, seed=0, texture_contrast=1.0)
    truth = synthesize(root / "truth", options)
    images = root / "guessed"
    shutil.copytree(truth / "images", images / "images")
    camera = json.loads((truth / "camera.json").read_text())
    (images / "camera.json").write_text(
        json.dumps({**camera, "fx": 0.8 * camera["fx"], "fy": 0.8 * camera["fy"]})
    )
    return images, camera["fx"]


@pytest.mark.slow
def test_the_refined_focal_length_is_the_true_one_and_is_written(guessed, tmp_path):
    images, true_fx = guessed
    out, report = tmp_path / "out", tmp_path / "report.json"
    argv = ["reconstruct", str(images), "--out", str(out), "--focal", "refine"]
    assert main([*argv, "--json", str(report)]) == 0
    focal = json.loads(report.read_text())["focal"]
    assert focal["status"] == "refined"
    # measured: 175.0 px from 0.8 x 172.8 (+1.3%), the second start within 0.1%
    assert focal["fx_fy_px"][0] == pytest.approx(true_fx, rel=0.03)
    assert focal["given_fx_fy_px"][0] == pytest.approx(0.8 * true_fx)
    assert focal["relative_difference"] <= _focal.AGREEMENT
    assert focal["aspect_change"] <= _focal.AGREEMENT
    written = json.loads((out / "camera.json").read_text())
    assert [written["fx"], written["fy"]] == focal["fx_fy_px"]
    # The guessed camera is left as it was.
    assert json.loads((images / "camera.json").read_text())["fx"] == pytest.approx(0.8 * true_fx)


@pytest.mark.slow
def test_starts_that_disagree_keep_the_given_focal_length(guessed, tmp_path, monkeypatch):
    images, true_fx = guessed
    monkeypatch.setattr(_focal, "AGREEMENT", 0.0)  # no two refinements agree this well
    report = reconstruct(images, tmp_path / "out", focal="refine", photometric=False)
    focal = report["focal"]
    assert focal["status"] == "undetermined" and "do not determine" in focal["note"]
    assert focal["fx_fy_px"] == focal["given_fx_fy_px"]
    written = json.loads((tmp_path / "out" / "camera.json").read_text())
    assert written["fx"] == pytest.approx(0.8 * true_fx)


def test_a_calibrated_camera_is_not_refined_and_bad_choices_are_named(guessed, tmp_path):
    images, _ = guessed
    distorted = tmp_path / "distorted"
    shutil.copytree(images, distorted)
    camera = json.loads((distorted / "camera.json").read_text())
    (distorted / "camera.json").write_text(json.dumps({**camera, "k1": -0.1}))
    with pytest.raises(CaptureError, match="calibrated"):
        reconstruct(distorted, tmp_path / "a", focal="refine")
    with pytest.raises(CaptureError, match="focal must be one of"):
        reconstruct(images, tmp_path / "b", focal="auto")
    # In place, the refined focal length would replace camera.json: only with --force.
    with pytest.raises(CaptureError, match=r"camera\.json: exists"):
        reconstruct(images, focal="refine")
