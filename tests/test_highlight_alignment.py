"""Whether the highlights sit at N = H, or one rotation of the normals puts them there
(`ctjax.specular.highlight_alignment`)."""

import dataclasses
import math

import numpy as np
import pytest
from test_sparkle_density import sparkly_capture

from ctjax._errors import CtjaxError
from ctjax.io import Capture
from ctjax.specular import (
    capture_sets,
    highlight_alignment,
    highlight_alignment_line,
    highlight_alignment_summary,
    highlight_peaks,
)
from ctjax.specular._highlight_alignment import _rotation, best_tilt


def _angle_deg(rotation: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(rotation) - 1) / 2, -1, 1)))


def _tilted(capture: Capture, rotation: np.ndarray) -> Capture:
    """`capture` with every stored normal turned by `rotation` (the frames have no pose:
    the camera frame is the world's)."""
    frames = tuple(
        dataclasses.replace(f, normals=(f.normals @ rotation.T).astype(np.float32))
        for f in capture.frames
    )
    return dataclasses.replace(capture, frames=frames)


def test_best_tilt_recovers_a_tilt_despite_outliers():
    rng = np.random.default_rng(0)
    half = rng.normal(size=(400, 3)) * [0.3, 0.3, 0.0] + [0.0, 0.0, -1.0]
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    true = half + rng.normal(0, 0.05, half.shape)  # peaks within a few degrees of N = H
    true[:80] = rng.normal(size=(80, 3)) * [1, 1, 0] + [0, 0, -1]  # a fifth far from it
    true /= np.linalg.norm(true, axis=-1, keepdims=True)
    tilt = _rotation(np.radians(25.0) * np.array([0.6, 0.8, 0.0]))
    stored = true @ tilt  # the reconstruction's normals: turned by tilt^-1
    found = best_tilt(stored, half)
    assert _angle_deg(found @ tilt.T) < 1.5  # found undoes it: found ~ tilt
    assert _angle_deg(found) == pytest.approx(25.0, abs=1.5)


def test_sparkles_about_the_right_normals_are_aligned(tmp_path):
    capture = sparkly_capture(tmp_path, 0.1, frames=8)
    result = highlight_alignment(capture)
    assert min(result.highlights) >= 20
    assert result.status == "aligned", result.reason
    assert result.angle_deg < 10 < result.all_pixels_angle_deg


def test_a_tilted_shape_is_found_and_the_tilt_measured(tmp_path):
    capture = sparkly_capture(tmp_path, 0.1, frames=8)
    tilt = _rotation(np.radians(20.0) * np.array([1.0, 0.0, 0.0]))
    result = highlight_alignment(_tilted(capture, tilt.T))
    assert result.status == "misoriented", result.reason
    assert result.rotation_deg == pytest.approx(20.0, abs=2.0)
    before, after = result.later_angle_deg
    assert before > 15 and after < 8
    assert "one rotation of the normals by" in result.reason
    assert "farther from N = H than the pixels at random" not in result.reason


def test_highlights_where_the_shape_faces_away_are_said_to_be_so(tmp_path):
    """Where the highlights' peaks lie farther from N = H than random pixels (a wall close
    to the scope whose surface structure from motion extrapolated: the full-resolution
    shared sinus), the reason says so, whatever the verdict."""
    capture = sparkly_capture(tmp_path, 0.1, frames=8)
    sets = capture_sets(capture)
    frames = []
    for frame, s in zip(capture.frames, sets, strict=True):
        h, w = s.specular.shape
        v, u = np.mgrid[0:h, 0:w]
        cam = capture.camera
        ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones((h, w))], -1)
        grazing = np.cross(ray, [0.0, 1.0, 0.0])  # perpendicular to the view
        grazing /= np.linalg.norm(grazing, axis=-1, keepdims=True)
        normals = frame.normals.copy()
        normals[s.specular] = grazing[s.specular]
        frames.append(dataclasses.replace(frame, normals=normals.astype(np.float32)))
    result = highlight_alignment(dataclasses.replace(capture, frames=tuple(frames)))
    assert result.angle_deg > result.all_pixels_angle_deg
    assert result.status in {"misoriented", "scattered"}
    assert "farther from N = H than the pixels at random" in result.reason


def test_normals_wrong_in_every_direction_are_scattered(tmp_path):
    capture = sparkly_capture(tmp_path, 0.1, frames=8, normal_error_deg=25.0)
    result = highlight_alignment(capture)
    assert result.status == "scattered", result.reason
    assert result.later_angle_deg[1] > 0.7 * result.later_angle_deg[0]


def test_too_few_highlights_and_what_cannot_be_measured(tmp_path):
    capture = sparkly_capture(tmp_path, 0.1, frames=2)
    sets = capture_sets(capture)
    peaks = highlight_peaks(capture, sets)
    result = highlight_alignment(capture, sets=sets, min_highlights=len(peaks))
    assert result.status == "too_few_highlights"
    assert "at least" in result.reason and math.isnan(result.rotation_deg)
    assert result.to_json()["rotation_deg"] is None
    one = dataclasses.replace(capture, frames=capture.frames[:1])
    block = highlight_alignment_summary(one, sets[:1])
    assert block["status"] == "not_measured" and "1 frame" in block["reason"]
    bare = dataclasses.replace(
        capture, frames=tuple(dataclasses.replace(f, normals=None) for f in capture.frames)
    )
    block = highlight_alignment_summary(bare, sets)
    assert block["status"] == "not_measured" and "normals" in block["reason"]
    assert highlight_alignment_line(block).startswith("highlight alignment: not_measured")


def test_h_from_a_near_lights_position(tmp_path):
    """A light 12 mm beside the lens (about 70 mm away): the peaks lie 6-8 degrees from the
    H of a light at the lens, and within 2.5 of the H of the light where it is."""
    from ctjax.io import load_capture
    from ctjax.synth import SynthOptions, synthesize

    offset = (12.0, 0.0, 0.0)
    options = SynthOptions(
        width=128, height=96, frames=4, texture=False, seed=2, effects={"light_offset": offset}
    )
    capture = load_capture(synthesize(tmp_path / "c", options))
    sets = capture_sets(capture)
    at_the_lens = highlight_peaks(capture, sets).angles_deg()
    where_it_is = highlight_peaks(capture, sets, offset).angles_deg()
    assert len(at_the_lens) == len(where_it_is) >= 4
    assert at_the_lens.min() > 5 and where_it_is.max() < 2.5
    no_depth = dataclasses.replace(
        capture, frames=tuple(dataclasses.replace(f, depth=None) for f in capture.frames)
    )
    with pytest.raises(CtjaxError, match="needs its depth"):
        highlight_peaks(no_depth, sets, offset)


def test_a_clipped_cores_peak_is_its_middle():
    """Pixels at the top (clipped) tie: the peak is the one nearest their centroid, not the
    first in raster order; an unclipped piece's peak is its brightest pixel."""
    from ctjax.specular._highlight_alignment import _peaks

    brightness = np.zeros((20, 30))
    brightness[2:9, 3:12] = 0.8
    brightness[4:7, 5:10] = 1.0  # a clipped core, 3 x 5 pixels: its middle is (5, 7)
    brightness[12:18, 15:25] = 0.5
    brightness[14, 21] = 0.7
    labels = np.zeros((20, 30), np.int32)
    labels[2:9, 3:12] = 1
    labels[12:18, 15:25] = 2
    ys, xs = _peaks(labels, 3, brightness)
    assert list(zip(ys.tolist(), xs.tolist(), strict=True)) == [(5, 7), (14, 21)]
