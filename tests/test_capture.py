"""The capture format: write/read round trip, normals from depth, and every loader error."""

import dataclasses
import json
import shutil

import cv2
import numpy as np
import pytest
from helpers import command_error, wavy_surface

import ctjax
from ctjax import Camera
from ctjax.io import Frame, load_capture, write_capture

CAMERA = Camera(40, 32, 38.0, 38.0, 19.5, 15.5)


def _frames(n=2, seed=0):
    rng = np.random.default_rng(seed)
    depth, normals = wavy_surface(CAMERA, seed)
    frames = []
    for k in range(n):
        image = np.round(rng.uniform(0, 1, (32, 40, 3)) * 255) / 255
        pose = np.eye(4)
        pose[:3, 3] = [k, 2 * k, 0.5]
        frames.append(
            Frame(
                f"f{k}",
                image.astype(np.float32),
                depth.astype(np.float32),
                normals.astype(np.float32),
                pose,
            )
        )
    return frames


@pytest.fixture
def capture_dir(tmp_path):
    return write_capture(tmp_path / "cap", CAMERA, _frames(), truth={"sigma": 0.2})


def test_round_trip(capture_dir):
    capture = load_capture(capture_dir)
    originals = _frames()
    assert [f.name for f in capture.frames] == ["f0", "f1"]
    assert capture.camera.to_json() == CAMERA.to_json()
    assert capture.truth == {"sigma": 0.2}
    for frame, original in zip(capture.frames, originals, strict=True):
        np.testing.assert_array_equal(frame.image, original.image)
        np.testing.assert_array_equal(frame.depth, original.depth)
        np.testing.assert_array_equal(frame.normals, original.normals)
        np.testing.assert_array_equal(frame.pose, original.pose)
        assert frame.image.dtype == np.float32 and frame.image.shape == (32, 40, 3)


def test_sixteen_bit_round_trip(tmp_path):
    frames = _frames(1)
    image = np.round(np.random.default_rng(1).uniform(0, 1, (32, 40, 3)) * 65535) / 65535
    frames = [Frame("a", image.astype(np.float32))]
    root = write_capture(tmp_path / "c16", CAMERA, frames, bits=16)
    raw = cv2.imread(str(root / "images" / "a.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    np.testing.assert_allclose(load_capture(root).frames[0].image, image, atol=1e-7)


def test_normals_partly_facing_away_are_noted(tmp_path):
    root = write_capture(tmp_path / "cap", CAMERA, _frames(2))
    assert load_capture(root).notes == ()
    normals = np.load(root / "normals" / "f1.npy")
    normals[:, ::5] *= -1  # every fifth column flipped: 20% seen from behind
    np.save(root / "normals" / "f1.npy", normals)
    (note,) = load_capture(root).notes
    assert "f1.npy: 20% of the normals face away from the camera" in note


def test_a_folder_with_other_frames_is_not_written_into(tmp_path):
    root = write_capture(tmp_path / "cap", CAMERA, _frames(3))
    write_capture(root, CAMERA, _frames(3))  # the same frames: replaced
    with pytest.raises(
        ctjax.CaptureError, match=r"images: holds images of other frames \(f2.png\)"
    ):
        write_capture(root, CAMERA, _frames(2))  # f2 would stay beside the new f0 and f1
    assert len(load_capture(root).frames) == 3


def test_rgb_channel_order(tmp_path):
    image = np.zeros((32, 40, 3), np.float32)
    image[..., 0] = 1.0  # pure red
    root = write_capture(tmp_path / "red", CAMERA, [Frame("r", image)])
    raw = cv2.imread(str(root / "images" / "r.png"))
    assert raw[0, 0].tolist() == [0, 0, 255]  # OpenCV stores BGR
    assert load_capture(root).frames[0].image[0, 0].tolist() == [1.0, 0.0, 0.0]


def test_normals_derived_from_depth(tmp_path):
    depth, normals = wavy_surface(CAMERA)
    root = write_capture(tmp_path / "d", CAMERA, [Frame("a", np.zeros((32, 40, 3)), depth)])
    derived = load_capture(root).frames[0].normals
    angle = np.degrees(np.arccos(np.clip(np.sum(derived * normals, -1), -1, 1)))
    assert np.median(angle) < 0.5 and np.max(angle) < 5


def test_normals_of_a_plane_from_depth_are_exact():
    # A tilted plane: n . P = d.
    n = np.array([0.2, -0.1, -1.0])
    n /= np.linalg.norm(n)
    u, v = np.meshgrid(np.arange(40.0), np.arange(32.0))
    rays = np.stack([(u - 19.5) / 38, (v - 15.5) / 38, np.ones_like(u)], -1)
    depth = -50.0 / (rays @ n)
    derived = ctjax._geometry.normals_from_depth(CAMERA, depth)
    np.testing.assert_allclose(derived, np.broadcast_to(n, derived.shape), atol=1e-5)


def test_undistortion_on_load(tmp_path):
    camera = Camera(40, 32, 38.0, 38.0, 19.5, 15.5, distortion=np.array([0.1, 0, 0, 0, 0]))
    image = np.full((32, 40, 3), 0.5, np.float32)
    root = write_capture(tmp_path / "dist", camera, [Frame("a", image)])
    assert json.loads((root / "camera.json").read_text())["k1"] == 0.1
    capture = load_capture(root)
    assert capture.camera.distortion is None
    assert capture.frames[0].image.shape == (32, 40, 3)
    np.testing.assert_allclose(capture.frames[0].image[16, 20], 0.5, atol=1 / 255)


def test_the_rational_models_terms_undistort_as_opencv_does(tmp_path):
    """k4, k5, k6 (OpenCV's rational model, a da Vinci's calibration): read, written back,
    and the images undistorted with all eight terms."""
    terms = np.array([0.2, -0.05, 0.001, -0.002, 0.01, 0.05, -0.02, 0.004])
    camera = Camera(80, 64, 60.0, 60.0, 39.5, 31.5, distortion=terms)
    v, u = np.mgrid[0:64, 0:80]
    image = np.stack([0.3 + 0.4 * (np.sin(u / 3.0) > 0), 0.2 + 0.002 * v, 0.4 + 0 * u], -1)
    root = write_capture(tmp_path / "rational", camera, [Frame("a", image.astype(np.float32))])
    described = json.loads((root / "camera.json").read_text())
    assert [described[k] for k in ("k4", "k5", "k6")] == [0.05, -0.02, 0.004]
    capture = load_capture(root)
    recorded = cv2.imread(str(root / "images" / "a.png"))[..., ::-1].astype(np.float32) / 255
    k = np.array([[60.0, 0, 39.5], [0, 60.0, 31.5], [0, 0, 1]])
    expected = cv2.remap(
        recorded, *cv2.initUndistortRectifyMap(k, terms, None, k, (80, 64), cv2.CV_32FC1),
        cv2.INTER_LINEAR,
    )  # fmt: skip
    np.testing.assert_allclose(capture.frames[0].image, expected, atol=1e-6)
    five = cv2.remap(
        recorded, *cv2.initUndistortRectifyMap(k, terms[:5], None, k, (80, 64), cv2.CV_32FC1),
        cv2.INTER_LINEAR,
    )  # fmt: skip
    assert np.mean(np.abs(five - expected)) > 1e-3  # the three terms matter here


def _break(root, how):
    if how == "missing folder":
        shutil.rmtree(root)
    elif how == "missing camera.json":
        (root / "camera.json").unlink()
    elif how == "malformed camera.json":
        (root / "camera.json").write_text("{width: 40")
    elif how == "missing key":
        (root / "camera.json").write_text(json.dumps({"width": 40, "height": 32, "fx": 38}))
    elif how == "zero focal length":
        data = json.loads((root / "camera.json").read_text())
        data["fx"] = 0
        (root / "camera.json").write_text(json.dumps(data))
    elif how == "non-finite intrinsics":
        (root / "camera.json").write_text(
            '{"width": 40, "height": 32, "fx": NaN, "fy": 38, "cx": 19.5, "cy": 15.5}'
        )
    elif how == "string intrinsics":
        data = json.loads((root / "camera.json").read_text())
        data["cy"] = "15.5"
        (root / "camera.json").write_text(json.dumps(data))
    elif how == "image size mismatch":
        cv2.imwrite(str(root / "images" / "f0.png"), np.zeros((10, 10, 3), np.uint8))
    elif how == "depth size mismatch":
        np.save(root / "depth" / "f0.npy", np.ones((31, 40), np.float32))
    elif how == "truncated image":
        data = (root / "images" / "f0.png").read_bytes()
        (root / "images" / "f0.png").write_bytes(data[: len(data) // 3])
    elif how == "grayscale image":
        cv2.imwrite(str(root / "images" / "f0.png"), np.zeros((32, 40), np.uint8))
    elif how == "rgba image":
        cv2.imwrite(str(root / "images" / "f0.png"), np.zeros((32, 40, 4), np.uint8))
    elif how == "empty images folder":
        for p in (root / "images").iterdir():
            p.unlink()
    elif how == "normals not unit":
        np.save(root / "normals" / "f0.npy", 2 * np.load(root / "normals" / "f0.npy"))
    elif how == "depth all NaN":
        np.save(root / "depth" / "f0.npy", np.full((32, 40), np.nan, np.float32))
    elif how == "corrupt depth file":
        (root / "depth" / "f0.npy").write_bytes(b"not numpy")
    elif how == "duplicate frames":
        shutil.copy(root / "images" / "f0.png", root / "images" / "f2.png")
    elif how == "one frame in two files":
        cv2.imwrite(str(root / "images" / "f1.jpg"), cv2.imread(str(root / "images" / "f1.png")))
    elif how == "malformed poses":
        (root / "poses.json").write_text(json.dumps({"f0": [[1, 0], [0, 1]]}))
    elif how in NOT_RIGID:
        pose = np.asarray(json.loads((root / "poses.json").read_text())["f1"])
        _edit(root / "poses.json", f1=(NOT_RIGID[how] @ pose).tolist())
    elif how in CAMERA_EDITS:
        _edit(root / "camera.json", **CAMERA_EDITS[how])
    else:
        raise AssertionError(how)


def _edit(path, **changes):
    path.write_text(json.dumps({**json.loads(path.read_text()), **changes}))


# Left-multiplied into a pose: a matrix that is not a rigid transform (F2 of the fuzz sweep).
NOT_RIGID = {
    "pose with a projective last row": np.array(
        [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0.1, 1.0]]
    ),
    "scaled pose": np.diag([2.0, 2.0, 2.0, 1.0]),
    "sheared pose": np.array([[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]),
    "reflected pose": np.diag([1.0, 1.0, -1.0, 1.0]),
}
CAMERA_EDITS = {
    "thin prism": {"k1": 0.1, "s1": 0.01, "s3": 0.001},
    "distortion array": {"distortion": [0.1, 0.01, 0.0, 0.0, 0.0]},
    "cx outside the image": {"cx": 5000},
    "focal length far too small": {"fx": 1e-300},
    "focal length in metres": {"fy": 1e6},
    "cy outside the image": {"cy": -3.5},
}


BAD = {
    "missing folder": "not found",
    "missing camera.json": "camera.json not found",
    "malformed camera.json": "not valid JSON",
    "missing key": "missing key",
    "zero focal length": "fx must be positive",
    "non-finite intrinsics": "must be finite",
    "string intrinsics": "must be a number",
    "image size mismatch": "camera.json says",
    "depth size mismatch": "depth has shape",
    "truncated image": "cannot read image",
    "grayscale image": "grayscale",
    "rgba image": "RGBA",
    "empty images folder": "no images",
    "normals not unit": "not unit",
    "depth all NaN": "no finite positive depth",
    "corrupt depth file": "cannot read depth",
    "malformed poses": "4x4",
    "focal length far too small": r"fx 1e-300 px is not a focal length for an image 40 px wide",
    "focal length in metres": r"fy 1e\+06 px is not a focal length for an image 32 px high",
    "one frame in two files": r"frame f1 has 2 images \(f1.jpg, f1.png\): keep one",
    "duplicate frames": r"duplicate frames \(identical images\): f2 = f0",
    "pose with a projective last row": r"poses.json: the pose of 'f1' is not a rigid transform "
    r"\(its last row is \[0.0, 0.0, 0.1, 1.05\], not \[0, 0, 0, 1\]\)",
    "scaled pose": "the pose of 'f1' is not a rigid transform .*a scale or a shear",
    "sheared pose": "the pose of 'f1' is not a rigid transform .*a scale or a shear",
    "reflected pose": "the pose of 'f1' is not a rigid transform .*a reflection",
    "thin prism": r"camera.json: unsupported distortion key\(s\) s1, s3: ctjax applies k1, k2, p1",
    "distortion array": r"unsupported distortion key\(s\) distortion:",
    "cx outside the image": r"camera.json: cx 5000 is outside the image \(0..40\)",
    "cy outside the image": r"camera.json: cy -3.5 is outside the image \(0..32\)",
}


@pytest.mark.parametrize("how", sorted(BAD), ids=sorted(BAD))
def test_loader_rejects_bad_input_with_one_clear_error(capture_dir, how):
    _break(capture_dir, how)
    with pytest.raises(ctjax.CaptureError, match=BAD[how]) as info:
        load_capture(capture_dir)
    assert isinstance(info.value, ValueError)
    assert "\n" not in str(info.value)


def test_loader_accepts_poses_rigid_to_float32_and_zero_unsupported_distortion(capture_dir):
    """What other tools write still loads: poses rounded to float32 (rotations rigid to
    ~1e-7), unused distortion keys set to zero, a principal point on the image's edge."""
    poses = json.loads((capture_dir / "poses.json").read_text())
    angle = 0.3
    turn = np.eye(4)
    turn[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    rounded = (turn @ np.asarray(poses["f1"])).astype(np.float32).astype(np.float64)
    _edit(capture_dir / "poses.json", f1=rounded.tolist())
    _edit(capture_dir / "camera.json", cx=40.0, cy=0.0, k4=0.0, distortion=[0, 0, 0, 0, 0])
    capture = load_capture(capture_dir)
    np.testing.assert_array_equal(capture.frames[1].pose, rounded)
    assert capture.camera.distortion is None and float(capture.camera.cx) == 40.0


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600)])
def test_outputs_respect_the_umask(tmp_path, umask, mode):
    """Results are written atomically (a temporary file, then a rename) with the mode a plain
    `open` gives: readable by others under the usual umask, private under a strict one."""
    import os

    from ctjax.io._atomic import atomic_write_json, atomic_write_npy

    previous = os.umask(umask)
    try:
        atomic_write_json(tmp_path / "a.json", {"sigma": 0.2})
        atomic_write_npy(tmp_path / "b.npy", np.zeros(3, np.float32))
    finally:
        os.umask(previous)
    for name in ("a.json", "b.npy"):
        assert (tmp_path / name).stat().st_mode & 0o777 == mode
    assert json.loads((tmp_path / "a.json").read_text()) == {"sigma": 0.2}
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary file left behind


def test_identical_frames_are_one_line_and_status_2(tmp_path, capsys):
    """Three identical frames (a still camera): every command stops with one line naming
    them, exit status 2, before any work."""
    frames = _frames(3)
    frames = [dataclasses.replace(f, image=frames[0].image) for f in frames]
    root = write_capture(tmp_path / "still", CAMERA, frames)
    status, lines = command_error(["diagnose", str(root), "--json", str(tmp_path / "d")], capsys)
    assert status == 2
    assert len(lines) == 1 and "duplicate frames" in lines[0] and "f1 = f0, f2 = f0" in lines[0]


@pytest.mark.parametrize("window", [5, 7, 11])
@pytest.mark.parametrize("deriv", [0, 1])
def test_savgol_coefficients_are_scipys(window, deriv):
    """The normals' Savitzky-Golay coefficients, written out (scipy.signal costs 0.2 s to
    import), against SciPy's."""
    from scipy.signal import savgol_coeffs

    from ctjax._geometry import savgol_coefficients

    np.testing.assert_allclose(
        savgol_coefficients(window, 3, deriv),
        savgol_coeffs(window, 3, deriv=deriv, use="dot"),
        atol=1e-13,
    )


def test_near_white_the_camera_turned_grey_reads_as_clipped(tmp_path):
    """In a frame of coloured tissue, bright pixels whose channels agree within one code
    value are the camera's desaturation, not the light's colour: read as clipped (1.0),
    with a note; a grey scene keeps its grey, and a dark grey pixel is kept."""
    from ctjax.io._desaturated import desaturated

    tissue = np.zeros((8, 8, 3), np.uint8)
    tissue[...] = (200, 90, 60)  # bright red mucosa
    tissue[0, :2] = (228, 228, 227)  # turned grey near white
    tissue[1, 0] = (120, 120, 120)  # grey, but dark: kept
    grey = desaturated(tissue)
    assert grey[0, :2].all() and grey.sum() == 2
    assert np.array_equal(desaturated(tissue.astype(np.uint16) * 257), grey)
    assert not desaturated(np.full((8, 8, 3), 230, np.uint8)).any()  # a grey scene
    write_capture(tmp_path / "c", Camera(8, 8, 8.0, 8.0, 3.5, 3.5), [Frame("a", tissue / 255.0)])
    capture = load_capture(tmp_path / "c")
    assert np.all(capture.frames[0].image[0, :2] == 1.0)
    assert np.all(capture.frames[0].image[1, 0] < 1.0)
    assert any("turned grey" in note for note in capture.notes)


def _tissue_samples(rng, n, ceiling=None):
    """(n, 3) codes of red tissue lit from dim to bright: every channel proportional to the
    light, red at most `ceiling` (the camera's), full scale clipped."""
    light = rng.uniform(0.05, 1.4, n)
    colour = np.array([1.0, 0.75, 0.7]) * rng.uniform(0.9, 1.1, (n, 3))
    codes = light[:, None] * colour * 250 + rng.normal(0, 2, (n, 3))
    if ceiling is not None:
        codes[:, 0] = np.minimum(codes[:, 0], ceiling + rng.normal(0, 3, n))
    return np.clip(np.round(codes), 0, 255).astype(np.uint8)


def _white_samples(rng, n, white=238):
    """(n, 3) codes of pale tissue lit from dim to overexposed by a camera whose white lies
    below full scale: every channel stops at `white`, give or take JPEG's chroma noise."""
    light = rng.uniform(0.05, 2.0, n)
    colour = np.array([1.0, 0.8, 0.75]) * rng.uniform(0.95, 1.05, (n, 3))
    codes = np.minimum(light[:, None] * colour * 250, white + rng.normal(0, 1.5, (n, 3)))
    return np.clip(np.round(codes + rng.normal(0, 1.5, (n, 3))), 0, 255).astype(np.uint8)


def test_a_camera_white_below_full_scale_reads_as_clipped_in_every_channel():
    """Every channel piling up at one code short of full scale is the camera's white: each
    reads as clipped from the pile's lower edge, 8- or 16-bit. One channel piling up alone
    (a red ceiling), the light rising to full scale, or a flat image's one colour is none."""
    from ctjax.io._channel_ceiling import channel_ceilings, white_level

    rng = np.random.default_rng(1)
    samples = _white_samples(rng, 200_000)
    ceilings = channel_ceilings(samples, 255)
    assert len(set(ceilings)) == 1 and 226 <= ceilings[0] <= 238
    wide = white_level(samples.astype(np.uint16) * 257, 65535)
    assert abs(wide - ceilings[0] * 257) <= 257
    assert white_level(_tissue_samples(rng, 100_000), 255) is None
    assert white_level(_tissue_samples(rng, 100_000, ceiling=170), 255) is None
    assert white_level(np.full((10_000, 3), 230, np.uint8), 255) is None
    assert white_level(_white_samples(rng, 150), 255) is None  # too few samples to say


def test_a_channel_the_camera_compressed_above_a_knee_is_named_not_clipped():
    """Red rising a third as fast above 170 as below (a camera's knee): no ceiling, a note
    that names it and `--effects knee`; none where red follows the light or stops (a
    ceiling), nor where the frames mix bit depths."""
    from ctjax.io._channel_ceiling import channel_ceilings, channel_knees, knee_note

    rng = np.random.default_rng(2)
    light = rng.uniform(0.05, 1.4, 100_000)
    codes = light[:, None] * np.array([1.0, 0.75, 0.7]) * rng.uniform(0.9, 1.1, (100_000, 3))
    codes = codes * 250 + rng.normal(0, 2, (100_000, 3))
    codes[:, 0] = np.where(codes[:, 0] > 170, 170 + (codes[:, 0] - 170) / 3, codes[:, 0])
    kneed = np.clip(np.round(codes), 0, 255).astype(np.uint8)
    assert channel_ceilings(kneed, 255) == [None, None, None]
    (knee,) = channel_knees([kneed[:50_000], kneed[50_000:]])
    assert knee.channel == 0 and 150 <= knee.level <= 185 and knee.above < knee.below / 2
    note = knee_note((knee,))
    assert note is not None and note.startswith("R rises 0.") and "--effects knee" in note
    assert channel_knees([_tissue_samples(rng, 100_000)]) == ()
    assert channel_knees([_tissue_samples(rng, 100_000, ceiling=170)]) == ()
    assert channel_knees([kneed, kneed.astype(np.uint16) * 257]) == ()
    assert channel_knees([]) == () and knee_note(()) is None


def test_a_channel_that_stops_below_full_scale_reads_as_clipped_there(tmp_path):
    """A channel that tops out below full scale while the others still rise (a white
    balance gain or colour matrix after the sensor clipped) is clipped there: its ceiling is
    found from the frames (`Capture.saturation`, with a note) and the observations read its
    values at or above it as clipped in that channel alone; channels that follow the light
    to full scale have none."""
    from ctjax.io._channel_ceiling import channel_ceilings
    from ctjax.io._stereo import StereoRig
    from ctjax.observations import Observations

    rng = np.random.default_rng(0)
    knee = channel_ceilings(_tissue_samples(rng, 100_000, ceiling=170), 255)
    assert knee[1:] == [None, None] and 160 <= knee[0] <= 175
    assert channel_ceilings(_tissue_samples(rng, 100_000), 255) == [None, None, None]
    # 16-bit frames: the same ceiling in their codes.
    wide = _tissue_samples(rng, 100_000, ceiling=170).astype(np.uint16) * 257
    assert 160 * 257 <= channel_ceilings(wide, 65535)[0] <= 175 * 257
    # Too few samples in the bright bins to say: none.
    assert channel_ceilings(_tissue_samples(rng, 500, ceiling=170), 255) == [None, None, None]

    camera = Camera(160, 160, 150.0, 150.0, 79.5, 79.5)
    frames = [_tissue_samples(rng, 160 * 160, 170).reshape(160, 160, 3) for _ in range(6)]
    write_capture(
        tmp_path / "c",
        camera,
        [
            Frame(f"f{k}", f / 255.0, np.full((160, 160), 50.0, np.float32))
            for k, f in enumerate(frames)
        ],
    )
    capture = load_capture(tmp_path / "c")
    (note,) = [note for note in capture.notes if "ceiling" in note]
    code = int(note.split("R from ")[1].split(" ")[0])
    assert 160 <= code <= 175
    # The level in the decoded images (linear 8-bit here); green and blue at full scale.
    # Half a code below the ceiling's: every decoding of that code is at or above it.
    assert capture.saturation == pytest.approx(((code - 0.5) / 255, 1.0, 1.0), rel=1e-6)
    for recorded, frame in zip(frames, capture.frames, strict=True):
        # The images as recorded; the observations read red clipped from the ceiling on.
        np.testing.assert_allclose(frame.image, recorded / 255, atol=1e-6)
    for recorded, usable in zip(frames, Observations(capture).usable, strict=True):
        clipped = (recorded[..., 0] >= code) | np.any(recorded[..., 1:] == 255, axis=-1)
        assert np.array_equal(usable[1:-1, 1:-1], ~clipped[1:-1, 1:-1])  # normals: not the rim
    assert capture.ceilings == (code, None, None)
    # `reconstruct` keeps what every frame showed in reconstruction.json, and a subset of
    # the frames (even or odd, fitted apart) reads its values as the whole did, even a
    # frame whose own values show no ceiling; camera.json's, where given, come first.
    strip = _tissue_samples(rng, 160 * 160).reshape(160, 160, 3)
    write_capture(tmp_path / "few", camera, [Frame("f0", strip / 255.0)])
    assert load_capture(tmp_path / "few").ceilings == (None, None, None)
    report = {"length_unit": "mm", "ceilings": [code, None, None]}
    (tmp_path / "few" / "reconstruction.json").write_text(json.dumps(report))
    few = load_capture(tmp_path / "few")
    assert few.saturation == pytest.approx(capture.saturation)
    assert few.ceilings == (code, None, None)
    assert any("reconstruction.json's ceilings" in note for note in few.notes)
    assert load_capture(tmp_path / "few", reconstructed_ceilings=False).ceilings == (None,) * 3
    described = json.loads((tmp_path / "few" / "camera.json").read_text())
    (tmp_path / "few" / "camera.json").write_text(json.dumps(described | {"ceilings": "none"}))
    assert load_capture(tmp_path / "few").ceilings == (None, None, None)
    plain = [_tissue_samples(rng, 160 * 160).reshape(160, 160, 3) for _ in range(6)]
    plain_frames = [Frame(f"f{k}", f / 255.0) for k, f in enumerate(plain)]
    write_capture(tmp_path / "p", camera, plain_frames)
    plain = load_capture(tmp_path / "p")
    assert not any("ceiling" in note for note in plain.notes)
    assert plain.ceilings == (None, None, None)
    assert plain.saturation == (1.0, 1.0, 1.0) == plain.right_saturation
    # camera.json's "ceilings": none, or given (codes of the images; null: full scale).
    described = json.loads((tmp_path / "c" / "camera.json").read_text())
    for declared, expected in (("none", (1.0, 1.0, 1.0)), ([180, None, 255], (179.5 / 255, 1, 1))):
        (tmp_path / "c" / "camera.json").write_text(json.dumps(described | {"ceilings": declared}))
        told = load_capture(tmp_path / "c")
        assert told.saturation == pytest.approx(expected, rel=1e-6)
        assert any("camera.json's ceilings" in n for n in told.notes) == (declared != "none")
    for wrong in ("sometimes", [180, None], [0, None, None], [180.5, None, None], True):
        (tmp_path / "c" / "camera.json").write_text(json.dumps(described | {"ceilings": wrong}))
        with pytest.raises(ctjax.CaptureError, match='"ceilings" must be'):
            load_capture(tmp_path / "c")
    # A stereo capture's right camera has its own: found on its images.
    rig = StereoRig(camera, np.eye(3), np.array([-5.0, 0.0, 0.0]))
    right = {f"f{k}": f / 255.0 for k, f in enumerate(frames)}
    write_capture(tmp_path / "s", camera, plain_frames, stereo=rig, right=right)
    stereo = load_capture(tmp_path / "s")
    assert stereo.saturation == (1.0, 1.0, 1.0)
    assert stereo.right_saturation == pytest.approx(capture.saturation)


def test_frames_reconstruct_did_not_register_are_left_out_with_a_note(tmp_path, capsys):
    """`ctjax reconstruct` keeps the images of the frames it could not register and lists
    them in reconstruction.json: the commands that fit leave them out and say which (they
    ended in "no depth or normals ...; reconstruct it first"); `masks` keeps every frame."""
    import argparse

    from ctjax._commands._args import load_capture as command_capture
    from ctjax.io import registered_frames

    rng = np.random.default_rng(0)
    camera = Camera(16, 16, 16.0, 16.0, 7.5, 7.5)
    images = [rng.uniform(0.2, 0.8, (16, 16, 3)) for _ in range(3)]
    depth = np.full((16, 16), 50.0, np.float32)
    frames = [Frame("a", images[0], depth), Frame("b", images[1]), Frame("c", images[2], depth)]
    write_capture(tmp_path / "c", camera, frames)
    capture = load_capture(tmp_path / "c")
    assert registered_frames(capture) == (capture, None)  # no report: as it is
    (tmp_path / "c" / "reconstruction.json").write_text(json.dumps({"unregistered": ["b"]}))
    kept, note = registered_frames(load_capture(tmp_path / "c"))
    assert [f.name for f in kept.frames] == ["a", "c"] and "1 of 3 frames" in note and "b" in note
    args = argparse.Namespace(capture=tmp_path / "c", command="fit")
    assert len(command_capture(args)) == 2
    assert "did not register in ctjax reconstruct (b;" in capsys.readouterr().err
    assert len(command_capture(args, registered_only=False)) == 3
    # A frame without its shape that the report does not list is the user's: as it is.
    (tmp_path / "c" / "reconstruction.json").write_text(json.dumps({"unregistered": []}))
    assert len(registered_frames(load_capture(tmp_path / "c"))[0]) == 3
