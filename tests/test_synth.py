"""Synthetic captures: the paper's model exactly, recoverable by an independent fit."""

import json
import math

import cv2
import numpy as np
import pytest

from ctjax.io import load_capture
from ctjax.synth import SynthOptions, synthesize


def _independent_fit(root, ring_px=10):
    """The paper's eq. (4)-(5) fitted with NumPy/OpenCV only, reading the files directly.

    Deliberately shares no code with ctjax: a check of the format and the units.
    """
    camera = json.loads((root / "camera.json").read_text())
    rows_a, rows_b, rows_c, values = [], [], [], []
    for path in sorted((root / "images").glob("*.png")):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1].astype(float) / 255
        depth = np.load(root / "depth" / f"{path.stem}.npy").astype(float)
        normals = np.load(root / "normals" / f"{path.stem}.npy").astype(float)
        hls = cv2.cvtColor(image.astype(np.float32), cv2.COLOR_RGB2HLS)
        specular = (hls[..., 1] >= 0.95) & (hls[..., 2] <= 0.05)
        distance = cv2.distanceTransform((~specular).astype(np.uint8), cv2.DIST_L2, 5)
        ring = (~specular) & (distance <= ring_px) & np.all(image < 1, -1)
        h, w = depth.shape
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        p = np.stack(
            [
                (u - camera["cx"]) / camera["fx"] * depth,
                (v - camera["cy"]) / camera["fy"] * depth,
                depth,
            ],
            -1,
        )
        view = -p / np.linalg.norm(p, axis=-1, keepdims=True)
        n_dot_l = np.sum(normals * view, -1)  # L = V
        ok = ring & (n_dot_l > 0.05)
        c = n_dot_l[ok]
        rows_a.append(c / math.pi)
        rows_b.append(1 / (math.pi * c * c * c**4))
        rows_c.append((1 - c**2) / c**2)
        values.append(image[ok])
    a, b, c = (np.concatenate(x) for x in (rows_a, rows_b, rows_c))
    values = np.concatenate(values)

    def solve(sigma):
        column = b * np.exp(-c / sigma**2) / sigma**2
        design = np.stack([a, column], -1)
        coefficients, cost = [], 0.0
        for channel in range(3):
            x, *_ = np.linalg.lstsq(design, values[:, channel], rcond=None)
            x = np.maximum(x, 0)
            coefficients.append(x)
            cost += np.sum((design @ x - values[:, channel]) ** 2)
        return cost, np.array(coefficients)

    grid = np.linspace(0.02, 1.0, 491)
    costs = [solve(s)[0] for s in grid]
    best = grid[int(np.argmin(costs))]
    fine = np.linspace(best - 0.004, best + 0.004, 161)
    sigma = fine[int(np.argmin([solve(s)[0] for s in fine]))]
    coefficients = solve(sigma)[1]
    return coefficients[:, 0], coefficients[:, 1], sigma, len(a)


@pytest.fixture(scope="module")
def plain_capture(tmp_path_factory):
    return synthesize(tmp_path_factory.mktemp("synth") / "cap", SynthOptions(texture=False))


def test_independent_fit_recovers_truth(plain_capture):
    truth = json.loads((plain_capture / "truth.json").read_text())
    rho, F, sigma, pixels = _independent_fit(plain_capture)
    assert pixels > 2000
    np.testing.assert_allclose(rho, truth["rho_tilde"], rtol=0.02)
    np.testing.assert_allclose(F, truth["F_tilde"], rtol=0.02)
    assert sigma == pytest.approx(truth["sigma"], rel=0.02)


def test_capture_contents(plain_capture):
    capture = load_capture(plain_capture)
    truth = capture.truth
    assert len(capture) == 5 and capture.has_geometry
    assert capture.camera.width == 320 and capture.camera.height == 256
    assert truth["effects"] == {} and truth["light"]["model"] == "colocated"
    for frame in capture.frames:
        assert np.all(np.isfinite(frame.depth)) and np.all(np.isfinite(frame.normals))
        assert 40 < np.nanmin(frame.depth) and np.nanmax(frame.depth) < 120
        # Highlights saturate, but only a small part of the image.
        saturated = np.mean(np.all(frame.image >= 1, axis=-1))
        assert 0 < saturated < 0.1
        # Normals face the camera and are unit.
        np.testing.assert_allclose(np.linalg.norm(frame.normals, axis=-1), 1, atol=1e-5)
        assert np.all(frame.normals[..., 2] < 0)
    # The camera moves between frames.
    centres = np.array([f.pose[:3, 3] for f in capture.frames])
    assert np.linalg.norm(centres[-1] - centres[0]) > 5


def test_same_seed_same_bytes(tmp_path):
    options = SynthOptions(width=64, height=48, frames=2, seed=3)
    a, b = synthesize(tmp_path / "a", options), synthesize(tmp_path / "b", options)
    for name in (
        "images/frame_001.png",
        "depth/frame_001.npy",
        "normals/frame_000.npy",
        "truth.json",
    ):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    c = synthesize(tmp_path / "c", SynthOptions(width=64, height=48, frames=2, seed=4))
    assert (a / "images/frame_001.png").read_bytes() != (c / "images/frame_001.png").read_bytes()


def test_texture_gives_sift_features(tmp_path):
    counts = {}
    for texture in (True, False):
        root = synthesize(tmp_path / str(texture), SynthOptions(frames=1, texture=texture))
        image = np.round(load_capture(root).frames[0].image * 255).astype(np.uint8)
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        counts[texture] = len(cv2.SIFT_create().detect(gray, None))
    assert counts[True] >= 300 and counts[True] > 10 * counts[False], counts


EFFECTS = {
    "light_offset": dict(effects={"light_offset": (6.0, 0.0, 0.0)}),
    "inverse_square": dict(effects={"inverse_square": True}),
    "spot_falloff": dict(effects={"spot_falloff": 4.0}),
    "camera_gamma": dict(effects={"camera_gamma": 2.2}),
    "ambient": dict(effects={"ambient": (0.04, 0.04, 0.04)}),
    "fresnel_schlick": dict(effects={"fresnel_schlick": 0.02, "light_offset": (6.0, 0.0, 0.0)}),
    # With L = V, G = min(1, 2 (N.V)^2) only acts beyond 45 degrees: visible with rough tissue.
    "geometric_attenuation": dict(effects={"geometric_attenuation": True}, sigma=0.6),
    "ggx": dict(effects={"ggx": True}),
    "second_lobe": dict(effects={"second_lobe": (0.6, 0.5)}),
}


@pytest.mark.parametrize("effect", sorted(EFFECTS), ids=sorted(EFFECTS))
def test_effects_change_the_images_and_are_recorded(tmp_path, effect):
    small = dict(width=64, height=48, frames=1, texture=False, noise_levels=0.0)
    sigma = EFFECTS[effect].get("sigma", SynthOptions.sigma)
    base = synthesize(tmp_path / "base", SynthOptions(**small, sigma=sigma))
    base = load_capture(base).frames[0].image
    root = synthesize(tmp_path / effect, SynthOptions(**small, **EFFECTS[effect]))
    capture = load_capture(root)
    assert effect in capture.truth["effects"]
    difference = np.abs(capture.frames[0].image - base).max() * 255
    assert difference >= 2, f"{effect} changed the image by {difference:.1f} levels only"
