"""Specular highlights on real-like endoscopic frames (`tests/reallike.py`): a bright liver
frame with tinted clipped highlights, a dim one where nothing clips, a colonoscopy frame
whose red clips over the tissue, with a black octagonal border and a white UI icon; on the
pale walls, white patches and bright rim of real frames (in miniature, and on the shared
real frames at a quarter of their size when `../shared/real` is there)."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from ctjax import ParameterError
from ctjax.cli import main
from ctjax.estimation import HLSThresholds, WhiterThanTissue, specular_mask, specular_sets
from ctjax.io import load_capture, visible_masks, white_overlays
from ctjax.io._images import write_rgb
from ctjax.synth import real_like_frame

KINDS = ("liver", "dim", "colon")


def _capture(root, frame) -> None:
    height, width = frame.image.shape[:2]
    camera = {"width": width, "height": height, "fx": 0.9 * width, "fy": 0.9 * width}
    # The synthetic frame is linear: say so (an undeclared 8-bit capture is decoded as sRGB).
    camera |= {"cx": width / 2, "cy": height / 2, "encoding": "linear"}
    root.mkdir(parents=True)
    (root / "camera.json").write_text(json.dumps(camera))
    write_rgb(root / "images" / "frame.png", frame.image)


def _read(path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED) > 127


@pytest.mark.parametrize("kind", KINDS)
def test_masks_with_the_defaults_find_the_highlights_of_a_real_like_frame(kind, tmp_path):
    frame = real_like_frame(kind, 480, 270, seed=1)
    _capture(tmp_path / "c", frame)
    assert main(["masks", str(tmp_path / "c"), "--out", str(tmp_path / "m")]) == 0
    specular = _read(tmp_path / "m" / "specular" / "frame.png")
    ring = _read(tmp_path / "m" / "ring" / "frame.png")
    # At least 70% of the near-white highlight pixels are in S ...
    near_white = frame.near_white
    assert near_white.sum() > 500
    assert (specular & near_white).sum() >= 0.7 * near_white.sum()
    # ... at least half of S lies within 7 px of the highlights (not on pale tissue) ...
    highlight = frame.specular >= 0.5 * np.max(frame.image, axis=-1)
    distance = cv2.distanceTransform((~highlight).astype(np.uint8), cv2.DIST_L2, 5)
    assert np.mean(distance[specular] <= 7) >= 0.5
    # ... nothing on the icon or outside the field of view, and a ring to fit.
    outside = frame.icon | ~frame.inside
    assert not (specular & outside).any() and not (ring & outside).any()
    assert ring.sum() > 0


def test_the_papers_rule_misses_dim_and_tinted_highlights():
    """HLS saturation divides by 2 - max - min: near white, any tint is 'saturated'."""
    for kind, at_most in (("dim", 0.05), ("liver", 0.95)):
        frame = real_like_frame(kind, 480, 270, seed=1)
        near_white = frame.near_white
        paper = specular_sets(frame.image, visible=frame.inside, highlights=HLSThresholds())
        default = specular_sets(frame.image, visible=frame.inside)
        assert (paper.specular & near_white).sum() <= at_most * near_white.sum()
        assert (default.specular & near_white).sum() >= 0.9 * near_white.sum()


def test_pale_tissue_is_not_a_highlight():
    """Fat is paler than the red tissue around it, but not whiter than the rule's bar."""
    rng = np.random.default_rng(0)
    image = np.empty((120, 160, 3), np.float32)
    image[:] = (0.62, 0.28, 0.2)
    image[30:60, 30:70] = (0.8, 0.68, 0.45)  # fat
    image += rng.normal(0, 1 / 255, image.shape).astype(np.float32)
    mask = WhiterThanTissue()(np.clip(image, 0, 1), np.ones((120, 160), bool))
    assert not mask.any()
    image[80:84, 100:106] += 0.5  # a highlight: fat and tissue stay out
    mask = WhiterThanTissue()(np.clip(image, 0, 1), np.ones((120, 160), bool))
    assert mask[80:84, 100:106].all() and mask.sum() == 24


def test_clipping_is_per_channel(tmp_path):
    """The colonoscope's red clips over much of the tissue: the green and blue there are
    measurements. 'Saturated' is written per channel (one colour of the PNG each)."""
    frame = real_like_frame("colon", 480, 270, seed=1)
    sets = specular_sets(frame.image, visible=frame.inside)
    share = sets.clipped[frame.inside].mean(axis=0)
    assert share[0] > 0.1 and share[1] < 0.02 and share[2] < 0.02
    _capture(tmp_path / "c", frame)
    assert main(["masks", str(tmp_path / "c"), "--out", str(tmp_path / "m")]) == 0
    written = cv2.imread(str(tmp_path / "m" / "saturated" / "frame.png"))[..., ::-1] > 127
    visible = load_capture(tmp_path / "c").frames[0].visible
    expected = specular_sets(frame.image, visible=visible).clipped
    np.testing.assert_array_equal(written, expected)


def test_a_white_icon_with_sharp_edges_is_an_overlay_in_one_frame():
    frame = real_like_frame("colon", 480, 270, seed=1)
    overlay = white_overlays([frame.image])
    assert overlay[frame.icon].all()
    # Clipped highlight cores fade into a halo whiter than the tissue: not overlays.
    assert not (overlay & frame.inside & (frame.specular > 0.3)).any()


def test_an_over_exposed_region_is_clipped_scene_not_an_overlay():
    """White over most of a frame, even with a sharp edge, is the scene at full scale: its
    pixels stay in view, in S or clipped (an icon is small)."""
    frame = real_like_frame("colon", 480, 270, seed=1)
    image = frame.image.copy()
    image[:, :300] = 1.0
    assert not white_overlays([image])[:, :300].any()
    visible = visible_masks([image])[0]
    white = frame.inside & ~frame.icon
    white[:, 300:] = False
    assert visible[white].mean() > 0.95  # less the field of view's margin by its border
    sets = specular_sets(image, visible=visible)
    assert (sets.specular | sets.saturated)[white & visible].all()


def test_the_paper_rule_and_its_thresholds_are_options(tmp_path, capsys):
    frame = real_like_frame("liver", 160, 90, seed=0)
    _capture(tmp_path / "c", frame)
    out = str(tmp_path / "m")
    assert main(["masks", str(tmp_path / "c"), "--out", out, "--highlights", "hls"]) == 0
    assert main(["masks", str(tmp_path / "c"), "--out", out, "--lightness", "0.9"]) == 2
    assert "--highlights hls" in capsys.readouterr().err


def _sinus_like(height=160, width=240, seed=0):
    """Linear values read off the sinus frames: red mucosa on the left, a pale wall close to
    the scope on the right (its red no brighter than the mucosa's, its green and blue far
    above), a little sensor noise."""
    rng = np.random.default_rng(seed)
    image = np.empty((height, width, 3), np.float32)
    image[:, : width // 2] = (0.72, 0.17, 0.14)  # mucosa
    image[:, width // 2 :] = (0.72, 0.53, 0.56)  # pale wall
    image *= (1 + 0.03 * rng.normal(size=(height, width, 1))).astype(np.float32)
    return image


def test_a_pale_wall_is_not_a_highlight_but_the_highlights_on_it_and_beside_it_are():
    """The pale wall is whiter than the mucosa beside it, but it is its own surroundings: only
    the two highlights are S (the rule before left the wall out of its own median, and
    took all of it)."""
    image = _sinus_like()
    image[40:46, 50:56] = 0.86  # on the mucosa
    image[110:116, 180:186] = 0.86  # on the wall
    visible = np.ones(image.shape[:2], bool)
    mask = WhiterThanTissue()(np.clip(image, 0, 1), visible)
    expected = np.zeros_like(visible)
    expected[40:46, 50:56] = expected[110:116, 180:186] = True
    np.testing.assert_array_equal(mask, expected)


def test_a_channel_at_the_cameras_ceiling_reads_as_clipped_for_s_too():
    """A camera whose white lies below full scale (a second sinus video: every channel stops
    at 233-239 of 255) writes a wall close to the scope, overexposed, at its ceiling with a
    few codes of JPEG's chroma noise, never at full scale: S's clip rule does not see it,
    and the pale ramp that leads up to it is nearly as bright, so the rest of the rule takes
    only part of it (93.7% here; 92.7% of that video's cores, `benchmarks/real_video.py`).
    With the capture's ceilings (`Capture.saturation`) the channels there read as clipped,
    and S takes all of it but isolated specks; below the ceiling the sets are as without."""
    rng = np.random.default_rng(2)
    image = _sinus_like()
    gain = np.linspace(0.6, 2.4, image.shape[1] - image.shape[1] // 2)[None, :, None]
    image[:, image.shape[1] // 2 :] = np.array([0.6, 0.44, 0.47]) * gain  # up to the scope
    image *= (1 + 0.03 * rng.normal(size=(*image.shape[:2], 1))).astype(np.float32)
    white = 0.84 * (1 + 0.02 * rng.normal(size=image.shape))  # 236 of 255, sRGB-decoded
    image = np.clip(np.minimum(image, white), 0, 1).astype(np.float32)
    ceiling = 0.80  # ~231 of 255
    at_ceiling = np.all(image >= ceiling, axis=-1)
    visible = np.ones(image.shape[:2], bool)
    plain = specular_sets(image, visible=visible)
    read = specular_sets(image, visible=visible, saturation_level=ceiling)
    assert plain.specular[at_ceiling].mean() < 0.97
    assert read.specular[at_ceiling].mean() > 0.99
    assert not (read.specular & ~at_ceiling & ~plain.specular).any()
    dark = image.max(axis=-1) < 0.6  # far below the ceiling: the same sets
    np.testing.assert_array_equal(plain.ring[dark], read.ring[dark])
    assert read.clipped.any(axis=-1)[at_ceiling & ~read.specular].all()


def test_a_white_patch_larger_than_the_window_is_found_whole():
    """White is not a tissue colour: a white patch wider than the median's window does not
    become its own surroundings (it is judged against the wall around it)."""
    image = _sinus_like()
    image[50:110, 150:210] = 0.8  # 60 px across, the window 20 px
    mask = WhiterThanTissue()(np.clip(image, 0, 1), np.ones(image.shape[:2], bool))
    assert mask[50:110, 150:210].all() and mask.sum() == 60 * 60


def test_the_bright_rim_of_the_field_of_view_is_not_s():
    """A bright ring just inside the image circle (light reflected inside the scope) is left
    out; a highlight inside the field of view is not, nor one cut by a cropped frame's
    edge (the image's edge is no rim)."""
    image = _sinus_like(240, 320)
    inside = np.zeros((240, 320), np.uint8)
    cv2.circle(inside, (160, 120), 110, 1, -1)
    visible = inside.astype(bool)
    ring = visible & ~cv2.erode(inside, np.ones((3, 3), np.uint8)).astype(bool)
    image[ring] = 0.9
    image[~visible] = 0.01
    image[100:106, 200:206] = 0.86
    mask = WhiterThanTissue()(np.clip(image, 0, 1), visible)
    assert not (mask & ring).any() and mask[100:106, 200:206].all()
    crop = _sinus_like()
    crop[0:4, 200:206] = 0.86  # cut by the top edge of the image
    mask = WhiterThanTissue()(np.clip(crop, 0, 1), np.ones(crop.shape[:2], bool))
    assert mask[0:4, 200:206].all() and mask.sum() == 24


def test_the_rules_parameters_are_checked():
    for field, value in (
        ("white", 1.5),
        ("grow", -0.1),
        ("outshine", 0.0),
        ("wide_window", 0.0),
        ("rim", float("nan")),
        ("contrast", -1.0),
    ):
        with pytest.raises(ParameterError, match=field):
            WhiterThanTissue(**{field: value})


# The shared real frames (../shared/real, beside the repository), at a quarter of their size.
REAL = Path(__file__).resolve().parents[2] / "shared" / "real"
SCALE = 4
CORE_LEVEL = 230  # every channel of a near-white core, in the recorded 8-bit image
RIM_PX = 15  # the field of view's bright rim at full resolution


def _srgb_decode(recorded: np.ndarray) -> np.ndarray:
    e = recorded.astype(np.float32) / 255
    return np.where(e <= 0.04045, e / 12.92, ((e + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _quarter(image: np.ndarray) -> np.ndarray:
    height, width = image.shape[:2]
    size = (round(width / SCALE), round(height / SCALE))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def _real_frames(sequence: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Recorded 8-bit RGB frames at a quarter size, and their fields of view."""
    if not REAL.is_dir():
        pytest.skip(f"../shared/real not found: {REAL}")
    if sequence == "jhu-sinus-a":
        # A small highlight on the mucosa beside a pale wall (0), tiny cores beside the
        # wall at its palest (12), a soft white patch on the wall just short of the cores'
        # level (15), and the same patch reaching it (24).
        folder = REAL / sequence
        files = sorted((folder / "images").glob("*.jpg"))
        if len(files) < 25:
            pytest.skip(f"../shared/real not found: {folder}/images is incomplete")
        frames = [_quarter(cv2.imread(str(files[i]))[..., ::-1]) for i in (0, 12, 15, 24)]
        mask = cv2.imread(str(folder / "undistorted_mask.bmp"), cv2.IMREAD_GRAYSCALE)
        fov = _quarter((mask > 127).astype(np.float32)) >= 0.5
        return frames, [fov] * len(frames)
    video = REAL / "lap-video" / "cholecystectomy.mp4"
    if not video.is_file():
        pytest.skip(f"../shared/real not found: {video}")
    capture = cv2.VideoCapture(str(video))
    frames = []
    for index in (0, 83, 166, 249):  # spread over the 250 frames
        capture.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, frame = capture.read()
        assert ok, f"frame {index} of {video}"
        frames.append(_quarter(frame[..., ::-1]))
    capture.release()
    # As `ctjax.io.load_capture` does: the field of view of the recorded values.
    return frames, visible_masks([frame.astype(np.float32) / 255 for frame in frames])


@pytest.mark.parametrize("sequence", ("jhu-sinus-a", "lap-video"))
def test_s_covers_the_near_white_cores_of_real_frames_and_little_else(sequence):
    """On real video, decoded to linear as ctjax decodes it: S holds at least 95% of the
    near-white cores (every channel >= 230 recorded, away from the field of view's rim)
    and at most 3 times the area of those cores dilated by 7x7 pixels."""
    frames, fields = _real_frames(sequence)
    radius = round(RIM_PX / SCALE)
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    cores_px = found_px = s_px = dilated_px = 0
    for recorded, visible in zip(frames, fields, strict=True):
        specular = specular_mask(_srgb_decode(recorded), visible=visible)
        inner = cv2.erode(visible.astype(np.uint8), disk).astype(bool)
        cores = np.all(recorded >= CORE_LEVEL, axis=-1) & inner
        dilated = cv2.dilate(cores.astype(np.uint8), np.ones((7, 7), np.uint8))
        cores_px += cores.sum()
        found_px += (cores & specular).sum()
        s_px += specular.sum()
        dilated_px += dilated.sum()
    assert cores_px > 100
    assert found_px >= 0.95 * cores_px, (found_px, cores_px)
    assert s_px <= 3 * dilated_px, (s_px, dilated_px)


def test_the_sinus_scopes_lens_edge_is_out_of_view():
    """The sinus scope's image circle ends in a white ring inside a dim halo (the lens's
    edge): ctjax's field of view (of the recorded frames, as `load_capture` finds it)
    leaves the ring out, and none of the tissue inside it. Until the lens's edge was
    looked for, every ring pixel was in view (counted as a near-white core, its halo as
    dark tissue): 197-341 per frame here."""
    frames, fields = _real_frames("jhu-sinus-a")  # the sequence's own mask of the circle
    visible = visible_masks([frame.astype(np.float32) / 255 for frame in frames])
    band = round(0.025 * frames[0].shape[1])  # `ctjax.io._field_of_view.RIM_BAND`
    for recorded, circle, fov in zip(frames, fields, visible, strict=True):
        inside = cv2.distanceTransform(circle.astype(np.uint8), cv2.DIST_L2, 3)
        ring = np.all(recorded >= CORE_LEVEL, axis=-1) & circle & (inside <= band)
        assert ring.sum() > 100  # the ring is there to leave out
        assert (ring & fov).sum() <= 0.1 * ring.sum()
        assert (fov & (inside > band)).sum() >= 0.99 * (inside > band).sum()
