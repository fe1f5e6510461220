"""Stereo captures: the format (camera.json's "stereo", right/NAME.png), `ctjax synth
--stereo`, the pairs' dense depth and `reconstruct` in millimetres without a size given."""

import dataclasses
import json
import re
import shutil

import cv2
import numpy as np
import pytest

from ctjax import CaptureError
from ctjax.cli import main
from ctjax.io import load_capture
from ctjax.sfm import reconstruct_capture
from ctjax.sfm._stereo import stereo_points
from ctjax.synth import SynthOptions, synthesize

BASELINE_MM = 5.0


@pytest.fixture(scope="module")
def stereo_capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("stereo") / "c"
    options = SynthOptions(width=192, height=160, frames=3, seed=1, stereo_mm=BASELINE_MM)
    return synthesize(root, options)


def test_synth_writes_the_right_camera_and_its_images(stereo_capture):
    described = json.loads((stereo_capture / "camera.json").read_text())
    assert described["stereo"]["T"] == [-BASELINE_MM, 0.0, 0.0]
    capture = load_capture(stereo_capture)
    assert capture.stereo.baseline_mm == pytest.approx(BASELINE_MM)
    right = capture.right_image(capture.frames[0].name)
    assert right.shape == capture.frames[0].image.shape
    # The same scene from 5 mm to the right: alike, not the same.
    assert 0 < np.mean(np.abs(right - capture.frames[0].image)) < 0.2


def test_the_pairs_measure_depth_in_millimetres(stereo_capture):
    capture = load_capture(stereo_capture)
    for index, frame in enumerate(capture.frames):
        points = stereo_points(capture, index)
        assert len(points) > 1000 and points.matched > 0.5
        rows = np.round(points.v).astype(int)
        cols = np.round(points.u).astype(int)
        true = frame.depth[rows, cols]
        ok = np.isfinite(true)
        error = points.z[ok] / true[ok] - 1
        assert abs(np.median(error)) < 0.005
        assert np.median(np.abs(error - np.median(error))) < 0.015


def test_reconstruct_is_metric_from_the_pairs_alone(stereo_capture, tmp_path):
    """No --scale-mm: the pairs give SfM's scale; depth within 0.5% of the truth."""
    images = tmp_path / "images-only"
    images.mkdir()
    for name in ("camera.json",):
        shutil.copy(stereo_capture / name, images / name)
    for folder in ("images", "right"):
        shutil.copytree(stereo_capture / folder, images / folder)
    truth = load_capture(stereo_capture)
    result = reconstruct_capture(load_capture(images), photometric=False)
    scale = result.report["scale"]
    assert scale["metric"] and scale["method"] == "stereo" and scale["unit"] == "mm"
    assert scale["stereo_scale_max_deviation"] < 0.01
    assert result.report["length_unit"] == "mm"
    assert result.report["stereo"]["baseline_mm"] == pytest.approx(BASELINE_MM)
    for frame in truth.frames:
        depth, _ = result.views[frame.name].depth_and_normals(truth.camera)
        ok = np.isfinite(depth) & np.isfinite(frame.depth)
        assert abs(np.median(depth[ok] / frame.depth[ok] - 1)) < 0.005


@pytest.mark.parametrize(
    "stereo, message",
    [
        (
            {"right": {"fx": 180, "fy": 180, "cx": 95.5, "cy": 79.5}, "R": np.eye(3).tolist()},
            "missing T",
        ),
        (
            {
                "right": {"fx": 180, "fy": 180, "cx": 95.5, "cy": 79.5},
                "R": [[2, 0, 0], [0, 1, 0], [0, 0, 1]],
                "T": [-5, 0, 0],
            },
            "rotation",
        ),
        (
            {
                "right": {"fx": 180, "cx": 95.5, "cy": 79.5},
                "R": np.eye(3).tolist(),
                "T": [-5, 0, 0],
            },
            "fy",
        ),
        (
            {
                "right": {"fx": 180, "fy": 180, "cx": 95.5, "cy": 79.5},
                "R": np.eye(3).tolist(),
                "T": [0, 0, 0],
            },
            "nonzero",
        ),
        ("left", "an object"),
        (  # the right camera's intrinsics are checked as the left's
            {
                "right": {"fx": 1, "fy": 180, "cx": 95.5, "cy": 79.5},
                "R": np.eye(3).tolist(),
                "T": [-5, 0, 0],
            },
            r"stereo.right\): fx 1 px is not a focal length for an image 192 px wide",
        ),
    ],
)
def test_a_bad_stereo_block_is_one_clear_error(stereo_capture, tmp_path, stereo, message):
    copy = tmp_path / "c"
    shutil.copytree(stereo_capture, copy)
    described = json.loads((copy / "camera.json").read_text())
    described["stereo"] = stereo
    (copy / "camera.json").write_text(json.dumps(described))
    with pytest.raises(CaptureError, match=message):
        load_capture(copy)


def test_a_baseline_in_metres_is_noted(stereo_capture, tmp_path):
    """T is in mm: 0.005 (metres) loads, with a note that says so; 5 mm says nothing."""
    copy = tmp_path / "c"
    shutil.copytree(stereo_capture, copy)
    assert not any("stereo.T" in note for note in load_capture(copy).notes)
    described = json.loads((copy / "camera.json").read_text())
    described["stereo"]["T"] = [-0.005, 0.0, 0.0]
    (copy / "camera.json").write_text(json.dumps(described))
    notes = [note for note in load_capture(copy).notes if "stereo.T is 0.005 mm" in note]
    assert len(notes) == 1 and "in millimetres" in notes[0]


def test_a_missing_right_image_is_named(stereo_capture, tmp_path):
    copy = tmp_path / "c"
    shutil.copytree(stereo_capture, copy)
    (copy / "right" / "frame_001.png").unlink()
    with pytest.raises(CaptureError, match="right image of frame_001 is missing"):
        load_capture(copy)


def test_a_right_image_of_another_size_is_named_where_it_is_read(stereo_capture, tmp_path):
    # Every user of the right images (the pairs, the right views of fit, evaluate and
    # calibrate-light) reads them through `Capture.right_image`, which checks the rig's size.
    copy = tmp_path / "c"
    shutil.copytree(stereo_capture, copy)
    path = copy / "right" / "frame_001.png"
    cv2.imwrite(str(path), cv2.resize(cv2.imread(str(path)), (96, 80)))
    capture = load_capture(copy)
    capture.right_image("frame_000")
    with pytest.raises(CaptureError, match=r"frame_001 is 96x80, the stereo camera .* 192x160"):
        capture.right_image("frame_001")


def test_near_white_turned_grey_reads_as_clipped_in_the_right_images(stereo_capture, tmp_path):
    # The same camera processing as the left frames (`ctjax.io._desaturated`): a grey
    # pixel near white in a frame of coloured tissue is clipped, a dark grey one is kept.
    copy = tmp_path / "c"
    shutil.copytree(stereo_capture, copy)
    path = copy / "right" / "frame_000.png"
    recorded = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    recorded[...] = (60, 90, 200)  # BGR: bright red mucosa
    recorded[0, :2] = (228, 228, 227)  # turned grey near white
    recorded[1, 0] = (120, 120, 120)  # grey, but dark
    cv2.imwrite(str(path), recorded)
    right = load_capture(copy).right_image("frame_000")
    assert np.all(right[0, :2] == 1.0)
    assert np.allclose(right[1, 0], 120 / 255) and np.allclose(
        right[2, 0], (200 / 255, 90 / 255, 60 / 255)
    )


def test_synth_command_stereo(tmp_path):
    out = tmp_path / "s"
    argv = ["synth", str(out), "--frames", "1", "--width", "64", "--height", "48"]
    # Untextured: the only seed-0 texture of this file (1.5 s drawn) for a file's existence.
    assert main([*argv, "--no-texture", "--stereo", "4"]) == 0
    assert (out / "right" / "frame_000.png").is_file()
    assert main(["synth", str(tmp_path / "bad"), "--stereo", "-1"]) == 2


def _video(path, images, held=3):
    height, width = images[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 24, (width, height))
    for image in images:
        bgr = np.round(np.clip(image[..., ::-1], 0, 1) * 255).astype(np.uint8)
        for _ in range(held):
            writer.write(bgr)
    writer.release()
    return path


def _opencv_calibration(path, described: dict, names=("M1", "D1", "M2", "D2", "R", "T")):
    """camera.json's content as an OpenCV calibration file (`cv::FileStorage`), under the
    names SCARED's endoscope_calibration.yaml gives them."""

    def matrix(camera):
        return np.array(
            [[camera["fx"], 0, camera["cx"]], [0, camera["fy"], camera["cy"]], [0, 0, 1]]
        )

    def distortion(camera):
        return np.array([[camera.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")]])

    stereo = described["stereo"]
    values = (
        matrix(described),
        distortion(described),
        matrix(stereo["right"]),
        distortion(stereo["right"]),
        np.array(stereo["R"], np.float64),
        np.array(stereo["T"], np.float64).reshape(3, 1),
    )
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in zip(names, values, strict=True):
        if name is not None:
            storage.write(name, value)
    storage.release()
    return path


def _davinci_calibration(path, described: dict, left_pose=None):
    """camera.json's content as a da Vinci's StereoCalibration.ini (StereoMIS's), the left
    camera at `left_pose` (R, T) in the rig's frame (default, as in the files: the identity
    and zero)."""
    left_pose = (np.eye(3), np.zeros(3)) if left_pose is None else left_pose
    stereo = described["stereo"]
    rotation = np.array(stereo["R"]) @ left_pose[0]
    translation = np.array(stereo["R"]) @ left_pose[1] + np.array(stereo["T"])
    lines = []
    for section, camera, (R, T) in (
        ("StereoLeft", described, left_pose),
        ("StereoRight", stereo["right"], (rotation, translation)),
    ):
        lines += [f"[{section}]", f"res_x={described['width']}", f"res_y={described['height']}"]
        lines += [f"fc_x={camera['fx']!r}", f"fc_y={camera['fy']!r}"]
        lines += [f"cc_x={camera['cx']!r}", f"cc_y={camera['cy']!r}"]
        terms = [camera.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")] + [0.0] * 3
        lines += [f"kc_{k}={value!r}" for k, value in enumerate(terms)]
        lines += [f"R_{k}={value!r}" for k, value in enumerate(np.ravel(R).tolist())]
        lines += [f"T_{k}={value!r}" for k, value in enumerate(np.ravel(T).tolist())]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    "layout",
    [
        "two videos",
        "two folders",
        "side by side",
        "top bottom",
        "top bottom, OpenCV's calibration",
        "top bottom, a da Vinci's calibration",
    ],
)
def test_import_writes_the_right_images_beside_the_left(stereo_capture, tmp_path, capsys, layout):
    capture = load_capture(stereo_capture)
    left = [frame.image for frame in capture.frames]
    right = [capture.right_image(frame.name) for frame in capture.frames]  # as recorded
    out = tmp_path / "imported"
    camera = stereo_capture / "camera.json"
    if layout.endswith("OpenCV's calibration"):
        described = json.loads(camera.read_text())
        camera = _opencv_calibration(tmp_path / "endoscope_calibration.yaml", described)
    if layout.endswith("a da Vinci's calibration"):  # StereoMIS's video and its file
        described = json.loads(camera.read_text())
        camera = _davinci_calibration(tmp_path / "StereoCalibration.ini", described)
    argv = ["import", "--camera", str(camera), "--out", str(out)]
    if layout == "two videos":
        argv += [str(_video(tmp_path / "l.mp4", left)), "--right"]
        argv += [str(_video(tmp_path / "r.mp4", right))]
    elif layout == "two folders":  # a dataset's frames: left/ and right/, the same names
        for side, images in (("left", left), ("right", right)):
            (tmp_path / side).mkdir()
            for k, image in enumerate(images):
                bgr = np.round(np.clip(image[..., ::-1], 0, 1) * 255).astype(np.uint8)
                cv2.imwrite(str(tmp_path / side / f"{k:04d}.png"), bgr)
        argv += [str(tmp_path / "left"), "--right", str(tmp_path / "right")]
        # A file missing on one side, or named apart: said, not paired with a neighbour.
        (tmp_path / "right" / "0001.png").rename(tmp_path / "right" / "0001b.png")
        assert main(argv) == 2
        assert "not named as" in capsys.readouterr().err
        (tmp_path / "right" / "0001b.png").unlink()
        assert main(argv) == 2
        assert "2 images where" in capsys.readouterr().err
        bgr = np.round(np.clip(right[1][..., ::-1], 0, 1) * 255).astype(np.uint8)
        cv2.imwrite(str(tmp_path / "right" / "0001.png"), bgr)
    elif layout == "side by side":
        pairs = [np.concatenate([a, b], axis=1) for a, b in zip(left, right, strict=True)]
        argv += [str(_video(tmp_path / "lr.mp4", pairs)), "--side-by-side"]
    else:  # SCARED's rgb.mp4: the left camera's image above the right one's
        pairs = [np.concatenate([a, b], axis=0) for a, b in zip(left, right, strict=True)]
        argv += [str(_video(tmp_path / "lr.mp4", pairs)), "--top-bottom"]
    if layout.startswith("top bottom"):  # the flag forgotten: said, not imported as one camera
        assert main([a for a in argv if a != "--top-bottom"]) == 2
        said = capsys.readouterr().err
        assert "two cameras' images" in said and "--top-bottom" in said
    json_report = tmp_path / "import.json"
    assert main([*argv, "--width", "128", "--json", str(json_report)]) == 0
    if layout.endswith("calibration"):
        said = capsys.readouterr().err
        source = "a da Vinci" if "da Vinci" in layout else "OpenCV"
        assert f"the camera from {source}'s calibration" in said and "a baseline of 5 mm" in said
    imported = load_capture(out)
    assert len(imported) == 3 and imported.stereo.right.width == 128
    assert imported.stereo.baseline_mm == pytest.approx(BASELINE_MM)
    assert json.loads(json_report.read_text())["baseline_mm"] == pytest.approx(BASELINE_MM)
    scale = 128 / capture.camera.width
    assert float(imported.stereo.right.fx) == pytest.approx(float(capture.camera.fx) * scale)
    assert np.allclose(imported.stereo.R, capture.stereo.R)
    assert float(imported.camera.cy) == pytest.approx(
        (float(capture.camera.cy) + 0.5) * scale - 0.5
    )
    image = imported.right_image(imported.frames[0].name)
    assert image.shape == (round(capture.camera.height * scale), 128, 3)
    # The right camera's image, not the left one's (they differ by the baseline's parallax).
    expected = cv2.resize(right[0], image.shape[1::-1], interpolation=cv2.INTER_AREA)
    other = cv2.resize(left[0], image.shape[1::-1], interpolation=cv2.INTER_AREA)
    assert np.mean(np.abs(image - expected)) < 0.5 * np.mean(np.abs(image - other))


def test_opencv_calibration_files_read_as_camera_json(stereo_capture, tmp_path):
    """What `import --camera FILE.yaml` reads: the same camera.json whatever the names, and
    one error naming the file and the matrix for what it cannot use."""
    from ctjax.io._opencv_calibration import camera_json_from_opencv

    described = json.loads((stereo_capture / "camera.json").read_text())
    size = (described["width"], described["height"])
    for suffix, names in ((".yaml", ("M1", "D1", "M2", "D2", "R", "T")),
                          (".xml", ("K1", "D1", "K2", "D2", "R", "T"))):  # fmt: skip
        path = _opencv_calibration(tmp_path / f"c{suffix}", described, names)
        read = camera_json_from_opencv(path, *size)
        assert read["fx"] == pytest.approx(described["fx"])
        assert read["stereo"]["right"]["cx"] == pytest.approx(described["stereo"]["right"]["cx"])
        assert np.allclose(read["stereo"]["T"], described["stereo"]["T"])
    # A plain YAML list of lists (not an !!opencv-matrix) reads too.
    (tmp_path / "plain.yaml").write_text("M1: [[300, 0, 95.5], [0, 310, 79], [0, 0, 1]]\n")
    plain = camera_json_from_opencv(tmp_path / "plain.yaml", *size)
    assert (plain["fx"], plain["fy"], plain["cx"], plain["cy"]) == (300, 310, 95.5, 79)
    # ROS's camera_info YAML (a da Vinci Research Kit's): rows, cols and data.
    ros = "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [300, 0, 95.5, 0, 310, 79, 0, 0, 1]\n"
    ros += "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.1, 0.01, 0, 0, 0]\n"
    (tmp_path / "ros.yaml").write_text(ros)
    ros = camera_json_from_opencv(tmp_path / "ros.yaml", *size)
    assert (ros["fy"], ros["cx"], ros["k1"], ros["k2"]) == (310, 95.5, -0.1, 0.01)
    # One camera: no stereo block.
    mono = _opencv_calibration(
        tmp_path / "mono.yaml", described, ("M1", "D1", None, None, None, None)
    )
    assert "stereo" not in camera_json_from_opencv(mono, *size)

    def error(path) -> str:
        with pytest.raises(CaptureError) as raised:
            camera_json_from_opencv(path, *size)
        return str(raised.value)

    assert "calibration file not found" in error(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("%YAML:1.0\n---\nM1: [1, 2\n")
    assert "bad.yaml" in error(tmp_path / "bad.yaml")
    (tmp_path / "words.yaml").write_text("M1:\n  rows: 3\n")
    assert "words.yaml: M1 is not a matrix of numbers" in error(tmp_path / "words.yaml")
    no_matrix = _opencv_calibration(
        tmp_path / "nom.yaml", described, ("A", "D1", None, None, None, None)
    )
    assert "no camera matrix (one of M1" in error(no_matrix)
    no_rt = _opencv_calibration(
        tmp_path / "nort.yaml", described, ("M1", "D1", "M2", "D2", None, None)
    )
    assert "without R and T" in error(no_rt)
    storage = cv2.FileStorage(str(tmp_path / "rational.yaml"), cv2.FILE_STORAGE_WRITE)
    storage.write("M1", np.array([[100.0, 0, 90], [0, 100, 80], [0, 0, 1]]))
    storage.write("D1", np.array([[0.1, 0.01, 0, 0, 0, 0, 0, 0, 0.2, 0, 0, 0]]))  # s1 = 0.2
    storage.release()
    assert "unsupported distortion key(s) s1" in error(tmp_path / "rational.yaml")


def test_a_stereo_import_needs_the_stereo_block(stereo_capture, tmp_path, capsys):
    described = json.loads((stereo_capture / "camera.json").read_text())
    del described["stereo"]
    camera = tmp_path / "camera.json"
    camera.write_text(json.dumps(described))
    frames = [frame.image for frame in load_capture(stereo_capture).frames]
    video = _video(tmp_path / "v.mp4", frames)
    argv = ["import", str(video), "--camera", str(camera), "--out", str(tmp_path / "o")]
    assert main([*argv, "--side-by-side"]) == 2
    assert "stereo" in capsys.readouterr().err
    assert main([*argv, "--side-by-side", "--top-bottom"]) == 2
    assert "--side-by-side or --top-bottom, not both" in capsys.readouterr().err
    guess = ["import", str(video), "--camera", "guess", "--out", str(tmp_path / "g")]
    assert main([*guess, "--top-bottom"]) == 2
    assert "needs the stereo calibration" in capsys.readouterr().err
    # T in metres: imported, with the warning that camera.json's T is in millimetres.
    described["stereo"] = json.loads((stereo_capture / "camera.json").read_text())["stereo"]
    described["stereo"]["T"] = [t / 1000 for t in described["stereo"]["T"]]
    camera.write_text(json.dumps(described))
    assert main([*argv, "--right", str(video), "--out", str(tmp_path / "m")]) == 0
    assert "stereo.T is 0.005 mm long" in capsys.readouterr().err
    # An OpenCV calibration of one camera only.
    storage = cv2.FileStorage(str(tmp_path / "mono.yaml"), cv2.FILE_STORAGE_WRITE)
    storage.write("M1", np.array([[300.0, 0, 95], [0, 300, 79], [0, 0, 1]]))
    storage.release()
    argv[3] = str(tmp_path / "mono.yaml")
    assert main([*argv, "--top-bottom"]) == 2
    assert "mono.yaml: a stereo import needs the right camera's matrix" in capsys.readouterr().err


@pytest.mark.slow
def test_the_near_light_fitted_with_the_shape(tmp_path, monkeypatch):
    """The shading refinement with a near light (`reconstruct --shading near`): the shape
    and the light's position fitted jointly, on a capture whose light sits off the lens.
    Here on the true shape (its plumbing and its bias; the reconstructed stereo captures'
    figures are in docs/user-guide/reconstruct.md: 0.3-0.9 mm at 320x256 x 8)."""
    from ctjax.sfm import _shading
    from ctjax.sfm._reconstruct import _shading_light

    monkeypatch.setattr(_shading, "MAX_POINTS", 2000)
    offset = (4.0, -3.0, 0.0)
    effects = {"light_offset": offset, "inverse_square": True}
    options = SynthOptions(width=192, height=160, frames=3, seed=3, effects=effects)
    capture = load_capture(synthesize(tmp_path / "c", options))
    light = _shading_light("near", capture)
    refined, report = _shading.refine_shape_by_shading(capture, light=light)
    assert report["cost_after"] < report["cost_before"]
    # In the lens plane (`LensPlaneLight`), as calibrate-light fits it.
    assert "LensPlaneLight fitted jointly (offset_mm)" in report["model"]
    assert report["light"]["length_unit"] == "mm"
    position = np.asarray(report["light"]["position_mm"])
    assert position[2] == 0 and report["light"]["offset_mm"] == list(position[:2])
    assert np.linalg.norm(position - offset) < 0.5  # measured: 0.31 mm (0.52 with the axis free)
    assert report["sigma_after"] == pytest.approx(0.2, rel=0.05)  # measured: 0.2004
    assert report["median_normal_change_deg"] < 1.0  # measured: 0.56
    for frame, before in zip(refined.frames, capture.frames, strict=True):
        ok = np.isfinite(before.depth)
        assert abs(np.median(frame.depth[ok] / before.depth[ok] - 1)) < 0.005


def test_the_light_is_fitted_from_a_sharp_and_a_broad_lobe():
    """The light-only descents start from roughnesses apart (a broad lobe with the light
    misplaced and a sharp one are two basins), not from the best starts alone: those were
    sigma 0.7 and 0.83 on a capture whose lobe is 0.2 (docs/user-guide/reconstruct.md)."""
    from ctjax.sfm._shading_starts import distinct_starts

    size = 3  # theta: 3 spline coefficients, then sigma
    starts = [
        (cost, np.array([0.0, 0.0, 0.0, sigma, 3.0, 0.0]))
        for cost, sigma in ((0.547, 0.7), (0.552, 0.83), (0.569, 0.2), (0.571, 0.15), (0.6, 0.05))
    ]
    sigmas = lambda chosen: [float(theta[size]) for _, theta in chosen]  # noqa: E731
    assert sigmas(distinct_starts(starts, size, 2)) == [0.7, 0.2]
    assert sigmas(distinct_starts(starts, size, 3)) == [0.7, 0.2, 0.05]
    assert [c for c, _ in distinct_starts(starts, size, 1)] == [0.547]


def test_an_unknown_shading_light_is_named(stereo_capture, tmp_path):
    from ctjax.sfm import reconstruct

    with pytest.raises(CaptureError, match="shading must be one of camera, near, got 'far'"):
        reconstruct(stereo_capture, tmp_path / "out", shading="far")


def test_the_shading_refinement_needs_a_shape(stereo_capture):
    from ctjax.sfm import _shading

    capture = load_capture(stereo_capture)
    images_only = dataclasses.replace(
        capture,
        frames=tuple(dataclasses.replace(f, depth=None, pose=None) for f in capture.frames),
    )
    with pytest.raises(CaptureError, match="needs every frame's depth, normals and pose"):
        _shading.refine_shape_by_shading(images_only)


@pytest.mark.slow
def test_a_refinement_that_bends_the_shape_is_not_kept(stereo_capture, monkeypatch):
    """Normals turned by more than `MAX_NORMAL_CHANGE_DEG` (median): the model does not
    explain the shading (12 real cholecystectomy frames: 45-53 degrees), the shape is kept."""
    from ctjax.sfm import _shading

    monkeypatch.setattr(_shading, "MAX_POINTS", 300)
    monkeypatch.setattr(_shading, "ITERATIONS", 1)
    monkeypatch.setattr(_shading, "MAX_NORMAL_CHANGE_DEG", 0.0)
    capture = load_capture(stereo_capture)
    kept, report = _shading.refine_shape_by_shading(capture)
    assert kept is capture
    assert "turned the normals by" in report["rejected"] and "shape kept" in report["rejected"]


def test_reconstruct_from_the_pairs_alone(stereo_capture, tmp_path):
    """`--stereo pairs` (a scope held still gives SfM no parallax): each frame's depth from
    its own pair, poses by PnP; measured 0.08-0.19 mm pose error over 5-10 mm of motion,
    depth -0.1..-0.3% in the median, normals 3.3-4.4 deg (SfM's with the pairs' scale: 0.5)."""
    from ctjax import ParameterError
    from ctjax.sfm import reconstruct

    out = tmp_path / "pairs"
    # The surfaces' knot spacing as given (the default here: 192 / 20 = 9.6 px).
    report = reconstruct(stereo_capture, out, stereo="pairs", knot_spacing_px=10.0)
    assert report["surface"]["knot_spacing_px"] == 10.0
    assert report["registered"] == ["frame_000", "frame_001", "frame_002"]
    assert report["length_unit"] == "mm" and report["mean_reprojection_error_px"] < 0.5
    truth, found = load_capture(stereo_capture), load_capture(out)
    assert found.length_unit == "mm" and found.stereo is not None
    first = np.linalg.inv(truth.frames[0].pose)
    for true, frame in zip(truth.frames, found.frames, strict=True):
        np.testing.assert_allclose(frame.pose[:3, 3], (first @ true.pose)[:3, 3], atol=0.5)
        ok = np.isfinite(frame.depth) & np.isfinite(true.depth)
        assert ok.mean() > 0.7
        assert abs(np.median(frame.depth[ok] / true.depth[ok] - 1)) < 0.005
        cosine = np.sum(frame.normals[ok] * true.normals[ok], axis=-1)
        assert np.median(np.degrees(np.arccos(np.clip(cosine, -1, 1)))) < 6
    with pytest.raises(ParameterError, match="no scale"):
        reconstruct(stereo_capture, tmp_path / "x", stereo="pairs", scale_mm=60.0)
    with pytest.raises(ParameterError, match=r"knot_spacing_px \(--knot-px\) must be a positive"):
        reconstruct(stereo_capture, tmp_path / "x", stereo="pairs", knot_spacing_px=0.0)


def test_a_stereo_capture_falls_back_to_its_pairs_where_sfm_fails(stereo_capture, monkeypatch):
    """A scope held still gives SfM no initial pair; a stereo capture is then reconstructed
    from its pairs (`--stereo pairs`), in mm, with the reason in the report. A mono capture,
    or a size given by the user, keeps SfM's error."""
    from ctjax import ReconstructionError
    from ctjax.sfm import _reconstruct

    reason = "structure-from-motion found no initial image pair among 3 frames"

    def no_pair(*args, **kwargs):
        raise ReconstructionError(reason)

    monkeypatch.setattr(_reconstruct, "sparse_with_focal", no_pair)
    capture = load_capture(stereo_capture)
    found = reconstruct_capture(capture, texture_smoothing=2.0)
    report = found.report
    assert report["sfm_failed"] == reason and found.sparse is None
    assert report["length_unit"] == "mm" and report["scale"]["method"] == "stereo"
    assert report["registered"] == ["frame_000", "frame_001", "frame_002"]
    assert report["warnings"][0].startswith(reason) and "--stereo pairs" in report["warnings"][0]
    assert "--texture-smoothing not applied" in report["warnings"][1]
    for mono in (dataclasses.replace(capture, stereo=None), capture):
        with pytest.raises(ReconstructionError, match="no initial image pair"):
            reconstruct_capture(mono, scale_mm=None if mono.stereo is None else 60.0)
    monkeypatch.setattr(_reconstruct, "pairs_reconstruction", lambda *a: no_pair())
    with pytest.raises(ReconstructionError, match="from the stereo pairs alone: structure"):
        reconstruct_capture(capture)


@pytest.mark.parametrize("registered, points", [(1, 500), (3, 5)])
def test_a_stereo_capture_falls_back_to_its_pairs_where_sfm_registers_too_little(
    stereo_capture, monkeypatch, registered, points
):
    """SfM that registers a few frames on a scope held nearly still (the real SurgT da Vinci
    clip: 3 of 10, on a baseline too short for any frame's surface) is not a reconstruction
    of a stereo capture: its pairs are, in mm. So are all frames registered whose points give
    the first frame no surface."""
    from ctjax.sfm import _reconstruct
    from ctjax.sfm._colmap import SparseModel

    capture = load_capture(stereo_capture)
    names = tuple(frame.name for frame in capture.frames)
    rng = np.random.default_rng(0)
    sparse = SparseModel(
        names=names,
        registered=names[:registered],
        cam_from_world={name: np.eye(4) for name in names[:registered]},
        points=rng.normal([0, 0, 60], [10, 10, 1], (points, 3)),
        point_errors=np.full(points, 0.5),
        track_lengths=np.full(points, 2),
        keypoints=dict.fromkeys(names, 1000),
        matching="exhaustive",
        mean_reprojection_error=0.5,
    )
    monkeypatch.setattr(
        _reconstruct, "sparse_with_focal", lambda *a: (sparse, capture.camera, {"focal": "fixed"})
    )
    reasons = []

    def pairs_instead(capture, error, *args):
        reasons.append(str(error))
        return "pairs"

    monkeypatch.setattr(_reconstruct, "_pairs_instead", pairs_instead)
    assert reconstruct_capture(capture) == "pairs"
    expected = "registered 1 of 3 frames" if registered == 1 else "first frame (frame_000) no"
    assert len(reasons) == 1 and expected in reasons[0]
    # A size given by the user keeps SfM's (the pairs are in mm with the given camera alone).
    if registered == 1:
        reconstruct_capture(capture, scale_mm=60.0)  # SfM's one frame, scaled as asked
        assert len(reasons) == 1


def test_a_da_vinci_calibration_reads_as_camera_json(stereo_capture, tmp_path):
    """`import --camera StereoCalibration.ini`: the da Vinci's sections read as camera.json
    (scaled for a smaller video, the pair's R and T composed where the left camera is not
    the rig's origin), and one error naming the file, section and key for what it lacks."""
    from ctjax.io._davinci_calibration import camera_json_from_davinci

    described = json.loads((stereo_capture / "camera.json").read_text())
    size = (described["width"], described["height"])
    path = _davinci_calibration(tmp_path / "StereoCalibration.ini", described)
    read = camera_json_from_davinci(path, *size)
    for key in ("fx", "fy", "cx", "cy"):
        assert read[key] == pytest.approx(described[key], rel=1e-12)
    np.testing.assert_allclose(read["stereo"]["R"], described["stereo"]["R"], atol=1e-12)
    np.testing.assert_allclose(read["stereo"]["T"], described["stereo"]["T"], atol=1e-12)
    # Frames half the calibrated size: intrinsics halved about the pixel centres.
    half = camera_json_from_davinci(path, size[0] // 2, size[1] // 2)
    assert half["fx"] == pytest.approx(described["fx"] / 2)
    assert half["cx"] == pytest.approx((described["cx"] + 0.5) / 2 - 0.5)
    assert half["stereo"]["right"]["fy"] == pytest.approx(described["stereo"]["right"]["fy"] / 2)
    # The left camera away from the rig's origin: the same pair.
    angle = np.radians(20)
    turn = np.array(
        [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    )
    moved = _davinci_calibration(tmp_path / "moved.ini", described, (turn, np.array([3.0, -1, 7])))
    composed = camera_json_from_davinci(moved, *size)["stereo"]
    np.testing.assert_allclose(composed["R"], described["stereo"]["R"], atol=1e-12)
    np.testing.assert_allclose(composed["T"], described["stereo"]["T"], atol=1e-12)

    text = path.read_text()
    rational = tmp_path / "rational.ini"  # the rational model's k4 (kc_5), as the file has it
    rational.write_text(text.replace("kc_5=0.0", "kc_5=0.01", 1))
    assert camera_json_from_davinci(rational, *size)["k4"] == 0.01
    for edit, message in (
        (text.replace("[StereoRight]", "[Other]"), "no [StereoRight] section"),
        (text.replace("fc_x=", "focal=", 1), "[StereoLeft] has no fc_x"),
        ("\n".join(line for line in text.splitlines() if not line.startswith("T_")) + "\n",
         "[StereoRight] has no T_0"),
        (text.replace("cc_y=", "cc_y=abc\nignored=", 1), "[StereoLeft] cc_y is not a number"),
        ("not an ini file", "not a da Vinci calibration file"),
    ):  # fmt: skip
        bad = tmp_path / "bad.ini"
        bad.write_text(edit)
        with pytest.raises(CaptureError, match=re.escape(message)) as raised:
            camera_json_from_davinci(bad, *size)
        assert str(bad) in str(raised.value)
    with pytest.raises(CaptureError, match=r"two cameras' images in each frame\? --top-bottom"):
        camera_json_from_davinci(path, size[0], 2 * size[1])
    with pytest.raises(CaptureError, match="another aspect"):
        camera_json_from_davinci(path, size[0], size[1] + 40)
