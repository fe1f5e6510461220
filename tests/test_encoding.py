"""How a capture's images encode light: sRGB or linear, declared in camera.json or taken
from the bit depth, decoded on load; written and imported captures say which."""

import json

import cv2
import numpy as np
import pytest

from ctjax import Camera, CaptureError
from ctjax.cli import main
from ctjax.io import Frame, load_capture, write_capture
from ctjax.io._encoding import linear_to_srgb, srgb_to_linear

CAMERA = Camera(24, 16, 20.0, 20.0, 11.5, 7.5)
LEVELS = np.arange(0, 256, dtype=np.uint8)


def _ramp_capture(root, encoding=None, dtype=np.uint8):
    """A capture of one image whose pixels run through the levels (BGR on disk)."""
    (root / "images").mkdir(parents=True)
    top = np.iinfo(dtype).max
    values = np.linspace(0, top, 24 * 16).round().astype(dtype).reshape(16, 24)
    image = np.stack([values, np.roll(values, 7), np.roll(values, 13)], axis=-1)
    cv2.imwrite(str(root / "images" / "a.png"), image)
    camera = CAMERA.to_json() | ({} if encoding is None else {"encoding": encoding})
    (root / "camera.json").write_text(json.dumps(camera))
    return image[..., ::-1].astype(np.float64) / top  # RGB, recorded values in [0, 1]


def test_the_srgb_curve_is_iec_61966_and_its_inverse():
    e = LEVELS / 255.0
    linear = srgb_to_linear(e)
    # Reference points of IEC 61966-2-1: the toe's slope, mid-grey, full scale.
    assert linear[0] == 0 and linear[-1] == 1.0
    assert srgb_to_linear(np.array(0.04045)) == pytest.approx(0.04045 / 12.92)
    assert srgb_to_linear(np.array(0.5)) == pytest.approx(0.21404, abs=1e-5)
    np.testing.assert_allclose(linear_to_srgb(linear), e, atol=1e-12)
    assert np.all(np.diff(linear) > 0)


@pytest.mark.parametrize(
    ("declared", "dtype", "expected", "noted"),
    [
        (None, np.uint8, "srgb", True),  # a JPEG or 8-bit frame of unknown encoding
        ("srgb", np.uint8, "srgb", False),
        ("linear", np.uint8, "linear", False),
        ("sRGB", np.uint8, "srgb", False),
        (None, np.uint16, "linear", False),  # 16 bits: a raw or a rendering
        ("srgb", np.uint16, "srgb", False),
    ],
)
def test_images_are_decoded_to_linear_intensity(tmp_path, declared, dtype, expected, noted):
    recorded = _ramp_capture(tmp_path / "cap", declared, dtype)
    capture = load_capture(tmp_path / "cap")
    assert capture.encoding == expected
    assert bool(capture.notes) == noted
    if noted:
        assert "decoded as sRGB" in capture.notes[0] and '"encoding"' in capture.notes[0]
    want = srgb_to_linear(recorded) if expected == "srgb" else recorded
    np.testing.assert_allclose(capture.frames[0].image, want, atol=1e-6)
    assert capture.frames[0].image.dtype == np.float32


def test_a_bad_encoding_is_one_capture_error(tmp_path):
    _ramp_capture(tmp_path / "cap", "gamma")
    with pytest.raises(CaptureError, match=r"camera.json: encoding must be one of 'srgb'"):
        load_capture(tmp_path / "cap")


def test_the_note_is_printed_once_by_a_command(tmp_path, capsys):
    _ramp_capture(tmp_path / "cap")
    assert main(["masks", str(tmp_path / "cap"), "--out", str(tmp_path / "masks")]) == 0
    err = capsys.readouterr().err
    assert err.count("ctjax masks: note: ") == 1 and "decoded as sRGB" in err


@pytest.mark.parametrize("encoding", ["linear", "srgb"])
def test_written_captures_say_their_encoding_and_read_back(tmp_path, encoding):
    rng = np.random.default_rng(0)
    linear = srgb_to_linear(np.round(rng.uniform(0, 1, (16, 24, 3)) * 255) / 255)
    if encoding == "linear":
        linear = np.round(rng.uniform(0, 1, (16, 24, 3)) * 255) / 255
    frame = Frame("a", linear.astype(np.float32))
    root = write_capture(tmp_path / "cap", CAMERA, [frame], encoding=encoding)
    assert json.loads((root / "camera.json").read_text())["encoding"] == encoding
    capture = load_capture(root)
    assert capture.encoding == encoding and capture.notes == ()
    np.testing.assert_allclose(capture.frames[0].image, linear, atol=1e-6)


def test_clipping_reads_the_same_in_either_encoding(tmp_path):
    recorded = _ramp_capture(tmp_path / "cap")
    image = load_capture(tmp_path / "cap").frames[0].image
    np.testing.assert_array_equal(image >= 1.0, recorded >= 1.0)


def test_the_field_of_view_is_found_on_the_recorded_values(tmp_path):
    # A dark border of level 14 (under the border's 15 of 255) around tissue of level 40:
    # decoded, the tissue is 0.021, under 15/255 = 0.059 in linear terms; the border must
    # be read on the recorded levels, not the tissue taken for it.
    (tmp_path / "cap" / "images").mkdir(parents=True)
    camera = Camera(96, 64, 80.0, 80.0, 47.5, 31.5)
    (tmp_path / "cap" / "camera.json").write_text(json.dumps(camera.to_json()))
    rng = np.random.default_rng(0)
    for k in range(2):
        image = np.full((64, 96, 3), 14, np.uint8)
        tissue = 40 + rng.integers(0, 30, (44, 76, 3))
        image[10:54, 10:86] = tissue.astype(np.uint8)
        cv2.imwrite(str(tmp_path / "cap" / "images" / f"f{k}.png"), image)
    frame = load_capture(tmp_path / "cap").frames[0]
    assert frame.field_of_view is not None
    assert frame.field_of_view[32, 48] and not frame.field_of_view[2, 2]
    assert frame.field_of_view[12:52, 12:84].mean() > 0.95
