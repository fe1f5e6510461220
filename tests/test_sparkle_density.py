"""Sigma from the density of the highlights over theta_h (`ctjax.specular.sparkle_density`)."""

import dataclasses
import json
import math
import shutil

import cv2
import numpy as np
import pytest

from ctjax._camera import Camera
from ctjax._errors import CtjaxError, ParameterError
from ctjax.cli import main
from ctjax.io import Capture, Frame, load_capture
from ctjax.specular import (
    capture_sets,
    sparkle_density,
    sparkle_density_line,
    sparkle_density_of_angles,
    sparkle_density_summary,
)
from ctjax.synth import SynthOptions, synthesize

WIDTH, HEIGHT, FOCAL = 256, 192, 220.0
# `ctjax synth --sparkles` at 160x128, 4 frames, seeds 0-2 (textured, 65-675 pixels in S):
# the sparkle density within -3.5..+10.3% of the effective sigma at sigma 0.2-0.4 (seed 0,
# here: +2.4% and +10.3%); at 320x256 x 8, +0.1..+8.0%. At sigma 0.1, +9.5..+24%: a facet
# is in S over a cone (where its own lobe passes the highlight rule) that is not small
# beside the facets' slopes.
SPARKLE_TOLERANCE = 0.15


def _view(camera: Camera) -> np.ndarray:
    u, v = np.meshgrid(np.arange(WIDTH, dtype=float), np.arange(HEIGHT, dtype=float))
    ray = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
    return -ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def _tangents(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t1 = np.cross(n, np.array([0.0, 1.0, 0.0]))
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    return t1, np.cross(n, t1)


def _smooth(rng, scale_px: float) -> np.ndarray:
    z = cv2.GaussianBlur(rng.normal(size=(HEIGHT, WIDTH)), (0, 0), scale_px)
    return z / z.std()


def sparkly_capture(
    tmp_path, sigma, *, frames=4, seed=0, sparkles=True, normal_error_deg=0.0, sigma_micro=0.06
):
    """Frames of wavy tissue (theta_h from 0 to about 60 degrees) whose highlights are
    sparkles: each pixel one facet, tilted from the surface's normal by a Beckmann slope of
    roughness `sigma` and lit by a sharp lobe (`sigma_micro`); the pixel-averaged lobe's
    sigma is their hypot. `sparkles=False`: one smooth lobe of roughness `sigma` (solid
    highlights). The stored normals are the surface's, tilted by a smooth random error of
    RMS `normal_error_deg`. 8-bit, one level of noise, clipped."""
    camera = Camera(WIDTH, HEIGHT, FOCAL, FOCAL, (WIDTH - 1) / 2, (HEIGHT - 1) / 2)
    view = _view(camera)
    rng = np.random.default_rng(seed)
    out = []
    for k in range(frames):
        u, v = np.meshgrid(np.arange(WIDTH, dtype=float), np.arange(HEIGHT, dtype=float))
        phase = rng.uniform(0, 2 * np.pi, 2)
        sx = 1.1 * np.sin(2 * np.pi * u / 170 + phase[0])
        sy = 1.1 * np.sin(2 * np.pi * v / 130 + phase[1])
        t1, t2 = _tangents(view)
        normal = view + sx[..., None] * t1 + sy[..., None] * t2
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        t1, t2 = _tangents(normal)
        if sparkles:
            p, q = (_smooth(rng, 1.5) * sigma / math.sqrt(2) for _ in range(2))
            facet = normal - p[..., None] * t1 - q[..., None] * t2
            facet /= np.linalg.norm(facet, axis=-1, keepdims=True)
            lobe, weight = sigma_micro, 0.1
        else:
            facet, lobe, weight = normal, sigma, 0.6
        cos_n = np.clip(np.sum(normal * view, -1), 0, 1)
        cos_f = np.clip(np.sum(facet * view, -1), 1e-3, 1)
        tan2 = 1 / cos_f**2 - 1
        specular = weight * np.exp(-tan2 / lobe**2) / (np.pi * lobe**2 * cos_f**6)
        texture = 1 + 0.2 * _smooth(rng, 6)
        albedo = np.array([1.8, 0.8, 0.6]) * texture[..., None]
        image = albedo / np.pi * cos_n[..., None] + specular[..., None]
        image = image + rng.normal(0, 1 / 255, image.shape)
        image = (np.round(np.clip(image, 0, 1) * 255) / 255).astype(np.float32)
        stored = normal
        if normal_error_deg:
            e = math.tan(math.radians(normal_error_deg)) / math.sqrt(2)
            stored = normal + e * (
                _smooth(rng, 20)[..., None] * t1 + _smooth(rng, 20)[..., None] * t2
            )
            stored /= np.linalg.norm(stored, axis=-1, keepdims=True)
        out.append(Frame(f"frame_{k:03d}", image, normals=stored.astype(np.float32)))
    return Capture(tmp_path, camera, tuple(out))


@pytest.mark.parametrize("sigma", [0.2, 0.4])
def test_recovers_sigma_from_sparkles(tmp_path, sigma):
    fit = sparkle_density(sparkly_capture(tmp_path, sigma), normal_error_deg=0.0)
    truth = math.hypot(sigma, 0.06)
    assert fit.status == "successful", fit.reason
    assert fit.sigma == pytest.approx(truth, rel=0.1)
    assert 0 < fit.rate < 0.99
    assert fit.halves is not None and all(h == pytest.approx(truth, rel=0.2) for h in fit.halves)


def test_normal_error_broadens_and_is_removed(tmp_path):
    truth = math.hypot(0.3, 0.06)
    capture = sparkly_capture(tmp_path, 0.3, normal_error_deg=10.0)
    unknown = sparkle_density(capture)
    assert unknown.status == "upper_bound"
    assert unknown.sigma > truth  # the normals' error only widens the lobe
    known = sparkle_density(capture, normal_error_deg=10.0)
    assert known.sigma_corrected == pytest.approx(truth, rel=0.15)


def test_solid_highlights_are_refused(tmp_path):
    fit = sparkle_density(sparkly_capture(tmp_path, 0.3, sparkles=False), normal_error_deg=0.0)
    assert fit.status == "solid_highlights"


def test_the_estimator_on_drawn_pixels():
    rng = np.random.default_rng(1)
    theta = np.arccos(rng.uniform(0.2, 1.0, 400_000))
    chance = 0.3 * np.exp(-(np.tan(theta) ** 2) / 0.25**2) / np.cos(theta) ** 3
    sigma, rate, rel = sparkle_density_of_angles(theta, rng.uniform(size=theta.size) < chance)
    assert sigma == pytest.approx(0.25, rel=0.03)
    assert rate == pytest.approx(0.3, rel=0.1)
    assert 0 < rel < 0.03


def test_bad_inputs(tmp_path):
    theta = np.linspace(0, 1, 100)
    with pytest.raises(ParameterError, match="empty"):
        sparkle_density_of_angles(theta, np.zeros(100, bool))
    with pytest.raises(ParameterError, match="non-finite"):
        sparkle_density_of_angles(np.where(theta > 0.5, np.nan, theta), theta < 0.1)
    with pytest.raises(ParameterError, match="alike"):
        sparkle_density_of_angles(theta, np.zeros(99, bool))
    with pytest.raises(ParameterError, match="every pixel"):
        sparkle_density_of_angles(theta, np.ones(100, bool))
    capture = sparkly_capture(tmp_path, 0.3, frames=1)
    with pytest.raises(ParameterError, match="normal_error_deg"):
        sparkle_density(capture, normal_error_deg=float("nan"))
    dull = Capture(
        tmp_path,
        capture.camera,
        tuple(
            Frame(f.name, np.full_like(f.image, 0.3) * [1, 0.5, 0.4], normals=f.normals)
            for f in capture.frames
        ),
    )
    with pytest.raises(ParameterError, match="S is empty"):
        sparkle_density(dull)
    no_shape = Capture(tmp_path, capture.camera, (Frame("a", capture.frames[0].image),))
    with pytest.raises(CtjaxError, match="without normals"):
        sparkle_density(no_shape)


# ---------------------------------------------------------------------------------------
# `ctjax fit`'s sparkle_density block and `ctjax synth --sparkles`.


@pytest.fixture(scope="module")
def small_capture(tmp_path_factory):
    options = SynthOptions(width=128, height=96, frames=4, texture=False, seed=2)
    return synthesize(tmp_path_factory.mktemp("sparkle") / "cap", options)


def test_fit_reports_the_sparkle_density(small_capture, tmp_path, capsys):
    out = tmp_path / "fit.json"
    assert main(["fit", str(small_capture), "--json", str(out), "--albedo", "uniform"]) == 0
    block = json.loads(out.read_text())["sparkle_density"]
    # synth's highlights are solid: the density is measured, and refused as sigma.
    assert block["status"] == "solid_highlights" and block["sigma"] > 0
    assert set(block) >= {
        "sigma",
        "sigma_rel_stderr",
        "rate",
        "halves",
        "status",
        "reason",
        "n_specular",
        "theta_h_median_deg",
        "theta_h_median_specular_deg",
    }
    assert set(block["halves"]) == {"even_frames", "odd_frames"}
    printed = capsys.readouterr().out
    assert "sparkle density: sigma" in printed
    # A few solid highlights a frame about the true normals: too few to tell, never tilted.
    alignment = json.loads(out.read_text())["highlight_alignment"]
    assert alignment["status"] == "too_few_highlights" and "at least 20" in alignment["reason"]
    assert "highlight alignment: too_few_highlights" in printed


def test_fit_warns_where_one_tilt_of_the_normals_places_the_highlights(
    small_capture, tmp_path, monkeypatch, capsys
):
    """Every normal turned 25 degrees (world): the highlights' peaks then sit 25 degrees
    from N = H in every frame, and the tilt fitted on the first frames' peaks brings the
    later frames' back; `fit` says the shape is misoriented (here with every peak counted:
    synth's solid highlights are a few a frame)."""
    import ctjax.specular._highlight_alignment as alignment_module

    monkeypatch.setattr(alignment_module, "MIN_HIGHLIGHTS", 1)
    copy = tmp_path / "cap"
    shutil.copytree(small_capture, copy)
    tilt = cv2.Rodrigues(np.radians(25.0) * np.array([1.0, 0.0, 0.0]))[0]
    for frame in load_capture(copy).frames:
        turn = frame.pose[:3, :3]
        turned = frame.normals.astype(np.float64) @ (turn.T @ tilt @ turn).T
        np.save(copy / "normals" / f"{frame.name}.npy", turned.astype(np.float32))
    out = tmp_path / "fit.json"
    assert main(["fit", str(copy), "--json", str(out), "--albedo", "uniform"]) == 0
    result = json.loads(out.read_text())
    block = result["highlight_alignment"]
    assert block["status"] == "misoriented", block["reason"]
    assert block["rotation_deg"] == pytest.approx(25.0, abs=3.0)
    assert block["later_frames_angle_deg_median"]["rotated"] < 5
    # Not a measurement of the lobe: its status says so (synth's lobe, sigma 0.2, comes out
    # far broader about these normals).
    assert result["status"] == "misoriented"
    last = result["undetermined"][-1]
    assert last["parameter"] == "sigma" and last["status"] == "misoriented"
    assert "shape's orientation is off" in capsys.readouterr().err


def test_fit_without_normals_on_the_highlights(small_capture, tmp_path, capsys):
    # No normal where S is: the intensity fit (on the ring) goes on, the block says why
    # there is no density.
    copy = tmp_path / "cap"
    shutil.copytree(small_capture, copy)
    capture = load_capture(copy)
    for frame, sets in zip(capture.frames, capture_sets(capture), strict=True):
        normals = frame.normals.copy()
        normals[sets.specular] = np.nan
        np.save(copy / "normals" / f"{frame.name}.npy", normals)
    out = tmp_path / "fit.json"
    assert main(["fit", str(copy), "--json", str(out), "--albedo", "uniform"]) == 0
    result = json.loads(out.read_text())
    assert result["sigma"] > 0
    block = result["sparkle_density"]
    assert block["status"] == "empty_specular_set" and block["sigma"] is None
    assert "S is empty" in block["reason"] and block["n_specular"] > 0
    assert "sparkle density: not measured (empty_specular_set)" in capsys.readouterr().out


def test_summary_without_normals(small_capture):
    capture = load_capture(small_capture)
    sets = capture_sets(capture)
    bare = dataclasses.replace(
        capture, frames=tuple(dataclasses.replace(f, normals=None) for f in capture.frames)
    )
    block = sparkle_density_summary(bare, sets)
    assert block["status"] == "no_normals" and "without normals" in block["reason"]
    assert block["sigma"] is None and block["n_specular"] > 0
    assert sparkle_density_line(block).startswith("sparkle density: not measured (no_normals)")


@pytest.mark.parametrize("sigma", [0.2, 0.4])
def test_synth_sparkles_recover_the_effective_sigma(tmp_path, sigma):
    size = ["--width", "160", "--height", "128", "--frames", "4", "--seed", "0"]
    assert main(["synth", str(tmp_path / "cap"), *size, "--sigma", str(sigma), "--sparkles"]) == 0
    capture = load_capture(tmp_path / "cap")
    truth = capture.truth
    assert truth["sigma"] == pytest.approx(math.hypot(sigma, 0.06))
    assert truth["sparkles"]["facet_sigma"] == sigma
    fit = sparkle_density(capture, normal_error_deg=0.0)
    assert fit.status == "successful", fit.reason
    assert fit.sigma == pytest.approx(truth["sigma"], rel=SPARKLE_TOLERANCE)
