"""`ctjax import`: a capture from a video written here with OpenCV (MPEG-4): 8 textured
views of a synthetic capture, each held for 6 frames as a still camera would, one of them
motion-blurred."""

import json

import cv2
import numpy as np
import pytest

from ctjax.cli import main
from ctjax.io import load_capture
from ctjax.io._video import ImportOptions
from ctjax.synth import SynthOptions, synthesize

HELD = 6


def _write_video(path, images, held=HELD, blurred=()):
    height, width = images[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 24, (width, height))
    assert writer.isOpened()
    for k, image in enumerate(images):
        bgr = np.round(np.clip(image[..., ::-1], 0, 1) * 255).astype(np.uint8)
        for repeat in range(held):
            writer.write(cv2.blur(bgr, (17, 1)) if (k, repeat) in blurred else bgr)
    writer.release()
    return path


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    root = tmp_path_factory.mktemp("video")
    # Small and strongly textured (as the demo's test), so SfM registers the views quickly.
    options = SynthOptions(width=192, height=160, frames=8, seed=2, texture_contrast=1.0)
    truth = synthesize(root / "truth", options)
    images = [frame.image for frame in load_capture(truth).frames]
    # The sharpest frame of a view is kept: blur one of the copies, and every copy but one.
    blurred = {(3, 2)} | {(5, r) for r in range(HELD) if r != 4}
    return _write_video(root / "v.mp4", images, blurred=blurred), truth / "camera.json"


def test_import_keeps_one_sharp_frame_per_view_and_reconstruct_registers_them(video, tmp_path):
    path, camera = video
    out = tmp_path / "capture"
    report = tmp_path / "import.json"
    argv = ["import", str(path), "--camera", str(camera), "--out", str(out)]
    assert main([*argv, "--json", str(report)]) == 0
    result = json.loads(report.read_text())
    assert 8 <= result["kept"] <= 16 and result["considered"] == 8 * HELD
    names = [f["name"] for f in result["frames"]]
    assert names == sorted(names) and len(set(names)) == len(names)
    # The view held with 5 blurred copies out of 6 keeps its sharp one (frame 5 * 6 + 4).
    assert f"frame_{5 * HELD + 4:06d}" in names
    capture = load_capture(out)
    assert len(capture.frames) == result["kept"]
    recon = tmp_path / "recon.json"
    # (SfM's points alone: the texture's refinement is test_sfm's.)
    assert main(["reconstruct", str(out), "--no-photometric", "--json", str(recon)]) == 0
    assert len(json.loads(recon.read_text())["registered"]) >= 6
    # Imported once: a second import asks for --force.
    assert main(argv) == 2
    assert main([*argv, "--force", "--every", "2", "--max-frames", "4"]) == 0
    assert len(list((out / "images").glob("*.png"))) == 4
    # The endoscope's camera.json says how its frames are encoded (this synthetic one:
    # linear), and the capture keeps it; where it does not say, video frames are sRGB.
    # --width resamples them with the intrinsics scaled (pixel centres kept).
    assert json.loads((out / "camera.json").read_text())["encoding"] == "linear"
    full = json.loads(camera.read_text())
    unsaid = tmp_path / "unsaid.json"
    unsaid.write_text(json.dumps({k: v for k, v in full.items() if k != "encoding"}))
    argv = ["import", str(path), "--camera", str(unsaid), "--out", str(out), "--force"]
    assert main([*argv, "--max-frames", "2", "--width", "32"]) == 0
    small = json.loads((out / "camera.json").read_text())
    assert small["encoding"] == "srgb" and load_capture(out).notes == ()
    # The shape reconstructed from the replaced frames went with them.
    assert not (out / "depth").exists() and not (out / "poses.json").exists()
    assert small["width"] == 32 and small["fx"] == pytest.approx(full["fx"] * 32 / full["width"])
    assert small["cx"] == pytest.approx((full["cx"] + 0.5) * 32 / full["width"] - 0.5)
    assert cv2.imread(str(next((out / "images").glob("*.png")))).shape[1] == 32


def _one_view(root):
    """A camera.json and one textured 64x48 image (no rendering needed)."""
    root.mkdir()
    camera = {"width": 64, "height": 48, "fx": 58.0, "fy": 58.0, "cx": 32.0, "cy": 24.0}
    (root / "camera.json").write_text(json.dumps(camera))
    rng = np.random.default_rng(0)
    texture = cv2.resize(rng.uniform(0.2, 0.8, (12, 16, 3)), (64, 48), cv2.INTER_CUBIC)
    return root / "camera.json", texture


def test_a_still_camera_gives_one_frame_and_a_warning(tmp_path, capsys):
    camera, image = _one_view(tmp_path / "t")
    path = _write_video(tmp_path / "still.mp4", [image], held=20)
    argv = ["import", str(path), "--camera", str(camera), "--out"]
    assert main([*argv, str(tmp_path / "c")]) == 0
    assert len(list((tmp_path / "c" / "images").glob("*.png"))) == 1
    assert "structure from motion needs views" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("content", "extra", "expected"),
    [
        # FFmpeg's own complaint in ctjax's one line, not on a line of its own before it.
        ("not a video", [], "cannot open the video (not a video OpenCV can decode: moov atom"),
        (None, ["--every", "0"], "--every must be a positive integer"),
        (None, ["--start", "5", "--end", "2"], "--end must be a time after --start"),
        # --width only shrinks: no silent upsampling of a 64-px video.
        (None, ["--width", "100"], "--width 100 cannot exceed the video's width (64 px)"),
        # 3 black frames: nothing in view (12 identical frames were kept).
        ("black", [], "no frame between --start and --end shows anything (black"),
    ],
)
def test_bad_imports_fail_with_one_line(tmp_path, capsys, content, extra, expected):
    camera, image = _one_view(tmp_path / "t")
    path = tmp_path / "v.mp4"
    if content in (None, "black"):
        _write_video(path, [image if content is None else 0 * image], held=3)
    else:
        path.write_text(content)
    argv = ["import", str(path), "--camera", str(camera), "--out"]
    assert main([*argv, str(tmp_path / "c"), *extra]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0]
    assert not (tmp_path / "c").exists()


def test_options_are_checked():
    with pytest.raises(Exception, match="--max-frames"):
        ImportOptions(max_frames=1)
    with pytest.raises(Exception, match="--width must be an integer >= 16"):
        ImportOptions(width=5)


def test_a_video_without_calibration_gets_a_guessed_camera(tmp_path, capsys):
    _, image = _one_view(tmp_path / "t")
    path = _write_video(tmp_path / "v.mp4", [image], held=3)
    assert main(["import", str(path), "--camera", "guess", "--out", str(tmp_path / "c")]) == 0
    camera = json.loads((tmp_path / "c" / "camera.json").read_text())
    height, width = image.shape[:2]
    assert (camera["width"], camera["height"]) == (width, height)
    assert camera["fx"] == camera["fy"] == pytest.approx(0.8 * width)
    assert (camera["cx"], camera["cy"]) == ((width - 1) / 2, (height - 1) / 2)
    assert camera["encoding"] == "srgb"
    assert "--focal refine" in capsys.readouterr().err
    # --width: the guess scaled with the frames, in the note as in camera.json.
    argv = ["import", str(path), "--camera", "guess", "--out", str(tmp_path / "c"), "--force"]
    assert main([*argv, "--width", "32"]) == 0
    camera = json.loads((tmp_path / "c" / "camera.json").read_text())
    assert camera["fx"] == pytest.approx(0.8 * 32)
    assert f"fx = fy = {0.8 * 32:.1f} px" in capsys.readouterr().err
    # A bad option is the one line, before any note; a stereo import has no guessed camera.
    assert main([*argv, "--every", "0"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "ctjax import: error: --every must be a positive integer, got 0"
    ]
    assert main([*argv, "--side-by-side"]) == 2
    err = capsys.readouterr().err
    assert "needs the stereo calibration" in err and "--camera guess has none" in err
    assert "note" not in err


def test_a_folder_of_images_imports_as_a_video_of_its_files(tmp_path, capsys):
    """A dataset's frames (SCARED's, Hamlyn's, the sinus's JPEGs): the files in name order
    are the video's frames, --start and --end count files, and each kept frame names its
    file in the report."""
    options = SynthOptions(width=96, height=80, frames=4, seed=2, texture_contrast=1.0)
    truth = synthesize(tmp_path / "truth", options)
    folder = tmp_path / "frames"
    folder.mkdir()
    views = [frame.image for frame in load_capture(truth).frames]
    for k, image in enumerate(views):  # each view twice: a still camera
        bgr = np.round(np.clip(image[..., ::-1], 0, 1) * 255).astype(np.uint8)
        for repeat in range(2):
            cv2.imwrite(str(folder / f"{1000 + 2 * k + repeat}.png"), bgr)
    (folder / "notes.txt").write_text("not an image")  # other files are left alone
    out, report = tmp_path / "capture", tmp_path / "import.json"
    argv = ["import", str(folder), "--camera", str(truth / "camera.json"), "--out", str(out)]
    assert main([*argv, "--json", str(report)]) == 0
    result = json.loads(report.read_text())
    assert result["considered"] == 8 and result["kept"] == 4
    assert [f["source"] for f in result["frames"]] == [
        "1000.png",
        "1002.png",
        "1004.png",
        "1006.png",
    ]
    first = cv2.imread(str(out / "images" / f"{result['frames'][0]['name']}.png"))
    assert np.array_equal(first, cv2.imread(str(folder / "1000.png")))
    assert main([*argv, "--force", "--start", "2", "--end", "5", "--json", str(report)]) == 0
    assert [f["source"] for f in json.loads(report.read_text())["frames"]] == [
        "1002.png",
        "1004.png",
    ]
    # Without a calibration: the guess from the first file's size.
    guessed = ["import", str(folder), "--camera", "guess", "--out", str(tmp_path / "g")]
    assert main(guessed) == 0
    assert json.loads((tmp_path / "g" / "camera.json").read_text())["fx"] == pytest.approx(0.8 * 96)
    # What it cannot use, named.
    cv2.imwrite(str(folder / "1008.png"), np.zeros((40, 96, 3), np.uint8))
    assert main([*argv, "--force"]) == 2
    assert "1008.png: 96x40 px where the folder's first frame is 96x80" in capsys.readouterr().err
    (folder / "1008.png").write_bytes(b"not a png")
    assert main([*argv, "--force"]) == 2
    assert "1008.png: cannot read the image" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    argv[1] = str(tmp_path / "empty")
    assert main(argv) == 2
    assert "empty: a folder without images" in capsys.readouterr().err
