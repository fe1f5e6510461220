"""Specular highlights on real-like endoscopic frames (`tests/reallike.py`): a bright liver
frame with tinted clipped highlights, a dim one where nothing clips, a colonoscopy frame
whose red clips over the tissue, with a black octagonal border and a white UI icon."""

import json

import cv2
import numpy as np
import pytest

from ctjax.cli import main
from ctjax.estimation import HLSThresholds, WhiterThanTissue, specular_sets
from ctjax.io import load_capture, white_overlays
from ctjax.io._images import write_rgb
from ctjax.synth import real_like_frame

KINDS = ("liver", "dim", "colon")


def _capture(root, frame) -> None:
    height, width = frame.image.shape[:2]
    camera = {"width": width, "height": height, "fx": 0.9 * width, "fy": 0.9 * width}
    camera |= {"cx": width / 2, "cy": height / 2}
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


def test_the_paper_rule_and_its_thresholds_are_options(tmp_path, capsys):
    frame = real_like_frame("liver", 160, 90, seed=0)
    _capture(tmp_path / "c", frame)
    out = str(tmp_path / "m")
    assert main(["masks", str(tmp_path / "c"), "--out", out, "--highlights", "hls"]) == 0
    assert main(["masks", str(tmp_path / "c"), "--out", out, "--lightness", "0.9"]) == 2
    assert "--highlights hls" in capsys.readouterr().err
