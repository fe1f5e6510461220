"""BRDF estimation: closed-form NNLS, the zooming BnB, the fit, the SOCP baseline, the CLI."""

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import command_error
from scipy.optimize import nnls as scipy_nnls

from ctjax.cli import main
from ctjax.estimation import (
    LAMBERTIAN,
    PAPER,
    TWO_SCALES,
    MaskOptions,
    colocated_samples,
    design_matrix,
    fit_brdf,
    fit_capture,
    grid_search,
    nnls,
    paper_coefficients,
    specular_sets,
)
from ctjax.estimation._samples import concatenate
from ctjax.io import load_capture
from ctjax.synth import SynthOptions, synthesize


@pytest.mark.parametrize("k", [1, 2, 3, 4])
@pytest.mark.parametrize("seed", range(6))
def test_closed_form_nnls_matches_scipy(k, seed):
    rng = np.random.default_rng(seed)
    design = rng.uniform(0, 1, (50, k))
    # Targets that make some coefficients want to be negative.
    values = design @ rng.normal(0, 1, (k, 3)) + rng.normal(0, 0.05, (50, 3))
    # Compiled, as the fitters use it (eagerly: 273 one-operation programs for these 24 cases).
    x, cost = jax.jit(nnls)(jnp.asarray(design), jnp.asarray(values))
    reference_cost = 0.0
    for c in range(3):
        reference, residual = scipy_nnls(design, values[:, c])
        np.testing.assert_allclose(np.asarray(x)[:, c], reference, atol=1e-9)
        reference_cost += residual**2
    assert float(cost) == pytest.approx(reference_cost, rel=1e-9)


def test_nnls_guards_zero_and_collinear_columns():
    rng = np.random.default_rng(0)
    a = rng.uniform(0.1, 1, 40)
    values = np.stack([2 * a, 3 * a, a], -1)
    for design in (np.stack([a, np.zeros(40)], -1), np.stack([a, 2 * a], -1)):
        x, cost = nnls(jnp.asarray(design), jnp.asarray(values))
        assert np.all(np.isfinite(np.asarray(x))) and np.isfinite(float(cost))
        assert float(cost) < 1e-12 * np.sum(values**2)
        np.testing.assert_allclose(np.asarray(design @ np.asarray(x)), values, atol=1e-9)


def _ring_samples(capture, ring_px=10, dtype=None):
    parts = []
    for frame in capture.frames:
        ring = specular_sets(frame.image, frame.geometry_mask, ring_px=ring_px).ring
        parts.append(colocated_samples(capture.camera, frame.image, frame.normals, ring, dtype))
    return concatenate(parts)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return load_capture(
        synthesize(tmp_path_factory.mktemp("est") / "c", SynthOptions(texture=False))
    )


def test_every_grid_cost_is_finite_even_when_the_specular_column_underflows(capture):
    samples = _ring_samples(capture)
    for sigma in (1e-5, 1e-4, 5e-4, 1e-3, 1.0):
        design = design_matrix(PAPER, jnp.array([sigma]), samples)
        x, cost = nnls(design, samples.values)
        assert np.isfinite(float(cost)) and np.all(np.isfinite(np.asarray(x)))
    assert float(jnp.max(design_matrix(PAPER, jnp.array([1e-5]), samples)[:, 1])) == 0.0


def test_fit_recovers_truth_within_two_percent(capture):
    fit = fit_brdf(_ring_samples(capture))
    truth = capture.truth
    assert float(fit.params[0]) == pytest.approx(truth["sigma"], rel=0.02)
    np.testing.assert_allclose(np.asarray(fit.weights[0]), truth["rho_tilde"], rtol=0.02)
    np.testing.assert_allclose(np.asarray(fit.weights[1]), truth["F_tilde"], rtol=0.02)
    # The model explains the ring down to the noise (1 level + quantisation).
    assert float(fit.rgb_rmse) < 1.1
    assert np.all(np.asarray(fit.params_stderr) < 0.01)


def test_float32_fit_agrees_with_float64(capture):
    wide = fit_brdf(_ring_samples(capture))
    narrow = fit_brdf(_ring_samples(capture, dtype=np.float32))
    assert narrow.weights.dtype == jnp.float32
    assert float(narrow.params[0]) == pytest.approx(float(wide.params[0]), abs=2e-3)
    np.testing.assert_allclose(np.asarray(narrow.weights), np.asarray(wide.weights), rtol=0.01)


_NARROW = """
import jax, numpy as np
assert not jax.config.jax_enable_x64
from ctjax.estimation import nnls_columns
rng = np.random.default_rng(0)
a, b = rng.uniform(0.1, 1, 5000), rng.uniform(0, 1, 5000) ** 8
y = np.stack([2 * a + 0.3 * b, a + 0.3 * b, 0.8 * a + 0.3 * b], -1)
y = y + rng.normal(0, 0.004, (5000, 3))
x, cost = nnls_columns((a.astype("f4"), b.astype("f4")), y.astype("f4"))
assert x.dtype == np.float32 and cost.dtype == np.float32
exact = np.linalg.lstsq(np.stack([a, b], -1), y, rcond=None)
print(float(cost) / float(exact[1].sum()) - 1, np.abs(np.asarray(x) - exact[0]).max())
"""


def test_float32_without_float64_forms_the_residuals():
    """Without jax_enable_x64 the float32 cost comes from explicit residuals: within 1e-3 of
    the exact least-squares cost (the normal-equation shortcut would lose ~3%)."""
    env = {**os.environ, "JAX_ENABLE_X64": "0"}
    out = subprocess.run(
        [sys.executable, "-c", _NARROW], capture_output=True, text=True, env=env, timeout=120
    )
    assert out.returncode == 0, out.stderr
    relative, weights = map(float, out.stdout.split())
    assert abs(relative) < 1e-3 and weights < 1e-3


def test_lambertian_fit_is_worse(capture):
    samples = _ring_samples(capture)
    assert float(fit_brdf(samples, LAMBERTIAN).rgb_rmse) > 5 * float(fit_brdf(samples).rgb_rmse)


@pytest.mark.parametrize("zoom_grid, evaluations", [(None, 32 + 2 * 4 * 32), (8, 32 + 3 * 4 * 8)])
def test_grid_search_finds_the_global_minimum_of_two_basins(zoom_grid, evaluations):
    # A wide shallow basin at 0.25 and a narrow deeper one at 0.81.
    def cost(p):
        x = p[0]
        return -jnp.exp(-(((x - 0.25) / 0.12) ** 2)) - 1.3 * jnp.exp(-(((x - 0.81) / 0.004) ** 2))

    dense = np.linspace(1e-5, 1, 2_000_001)
    brute = dense[np.argmin(np.asarray(cost(jnp.asarray(dense)[None])))]
    result = grid_search(cost, 1e-5, 1.0, zoom_grid=zoom_grid)
    assert result.evaluations == evaluations
    assert abs(float(result.params[0]) - brute) <= 1e-3
    # No worse than the brute-force minimum moved by the final grid's half spacing.
    half = float(result.half_width[0])
    worst = max(float(cost(jnp.array([brute + d]))) for d in (-half, half))
    assert float(result.cost) <= worst + 1e-6


@pytest.mark.parametrize("coarse_levels", [1, 2, 10])
def test_grid_search_coarse_first_level_keeps_the_basins_and_reports_the_cost(coarse_levels):
    # The first levels on a cheaper cost of another scale (a subset of the samples sums
    # less): the same minimum, and the reported cost is `cost`'s, not the coarse one's (10
    # levels asked: all but the last).
    def cost(p):
        x = p[0]
        return -jnp.exp(-(((x - 0.25) / 0.12) ** 2)) - 1.3 * jnp.exp(-(((x - 0.81) / 0.02) ** 2))

    plain = grid_search(cost, 1e-5, 1.0, zoom_grid=8)
    coarse = grid_search(
        cost,
        1e-5,
        1.0,
        zoom_grid=8,
        coarse=lambda p: 0.25 * cost(p) - 7.0,
        coarse_levels=coarse_levels,
    )
    assert abs(float(coarse.params[0]) - 0.81) <= 1e-3
    assert float(coarse.params[0]) == pytest.approx(float(plain.params[0]), abs=1e-12)
    assert float(coarse.cost) == pytest.approx(float(cost(coarse.params)), rel=1e-9)


def test_brdf_cost_with_two_basins_matches_brute_force(tmp_path):
    # Two lobes in the data, one in the model: the cost over sigma has two basins.
    options = SynthOptions(
        width=160,
        height=128,
        frames=3,
        texture=False,
        sigma=0.08,
        effects={"second_lobe": (0.45, 1.5)},
    )
    samples = _ring_samples(load_capture(synthesize(tmp_path / "two", options)), ring_px=12)
    fit = fit_brdf(samples)

    @jax.jit
    @jax.vmap
    def cost(sigma):
        return nnls(design_matrix(PAPER, sigma[None], samples), samples.values)[1]

    dense = np.linspace(1e-3, 1, 4000)
    costs = np.asarray(cost(jnp.asarray(dense)))
    best = dense[np.argmin(costs)]
    assert float(fit.cost) <= costs.min() * (1 + 1e-6)
    assert abs(float(fit.params[0]) - best) < 1e-3 + (dense[1] - dense[0])


@pytest.mark.slow
def test_two_scale_family_recovers_two_lobes(tmp_path):
    # Dim tissue, so that the sharp lobe is not hidden under saturated pixels.
    options = SynthOptions(
        width=160,
        height=128,
        frames=3,
        texture=False,
        rho_tilde=(0.8, 0.5, 0.4),
        F_tilde=(0.2, 0.2, 0.2),
        sigma=0.12,
        effects={"second_lobe": (0.4, 0.5)},
        noise_levels=0.5,
    )
    samples = _ring_samples(load_capture(synthesize(tmp_path / "two", options)), ring_px=15)
    fit = fit_brdf(samples, TWO_SCALES, grid=16)
    sigmas = sorted(np.asarray(fit.params).tolist())
    assert sigmas[0] == pytest.approx(0.12, rel=0.05)
    assert sigmas[1] == pytest.approx(0.4, rel=0.1)
    assert float(fit.rgb_rmse) < float(fit_brdf(samples).rgb_rmse)


@pytest.mark.slow
def test_socp_baseline_and_closed_form_agree(capture):
    from ctjax.baselines import socp_branch_and_bound

    samples = _ring_samples(capture)
    a, b, c = paper_coefficients(samples)
    socp = socp_branch_and_bound(a, b, c, np.asarray(samples.values))
    # The same branch-and-bound, centre for centre, with the closed form: same sigma and cost.
    paper_bnb = fit_brdf(samples, grid=10, candidates=1, zoom=1)
    assert float(paper_bnb.params[0]) == pytest.approx(socp.sigma, abs=1e-12)
    assert float(paper_bnb.cost) == pytest.approx(socp.cost, rel=1e-6)
    np.testing.assert_allclose(np.asarray(paper_bnb.weights[0]), socp.rho_tilde, rtol=1e-5)
    # ctjax's default search: the same sigma within the final interval length, lower cost.
    default = fit_brdf(samples)
    assert abs(float(default.params[0]) - socp.sigma) <= 1e-3
    assert float(default.cost) <= socp.cost * (1 + 1e-9)


def test_masks_and_fit_commands(capture, tmp_path, capsys):
    assert main(["masks", str(capture.root), "--out", str(tmp_path / "m"), "--ring-px", "10"]) == 0
    for kind in ("specular", "ring", "saturated"):
        assert len(list((tmp_path / "m" / kind).glob("*.png"))) == len(capture)
    out = tmp_path / "fit.json"
    argv = ["fit", str(capture.root), "--json", str(out)]
    # Depth and poses in every frame: the albedo map by default, right on untextured tissue.
    assert main(argv) == 0
    result = json.loads(out.read_text())
    truth = capture.truth
    assert result["albedo"] == "map" and result["warnings"] == []
    assert result["sigma"] == pytest.approx(truth["sigma"], rel=0.02)
    np.testing.assert_allclose(result["rho_tilde"], truth["rho_tilde"], rtol=0.02)
    np.testing.assert_allclose(result["F_tilde"], truth["F_tilde"], rtol=0.02)
    # The paper's model: one albedo, fitted on the ring.
    assert main([*argv, "--albedo", "uniform", "--ring-px", "10"]) == 0
    result = json.loads(out.read_text())
    assert result["albedo"] == "uniform"
    assert result["sigma"] == pytest.approx(truth["sigma"], rel=0.02)
    np.testing.assert_allclose(result["rho_tilde"], truth["rho_tilde"], rtol=0.02)
    np.testing.assert_allclose(result["F_tilde"], truth["F_tilde"], rtol=0.02)
    assert result["n_ring_pixels"] > 2000 and result["rgb_rmse"] < 1.1
    assert result["lambertian"]["rgb_rmse"] > 5 * result["rgb_rmse"]
    assert result["warnings"] == []
    # The paper's 3 px ring around the paper's S (HLS, clipped white cores only) is thin
    # here: the fit says so.
    assert main([*argv, "--albedo", "uniform", "--highlights", "hls"]) == 0
    assert json.loads(out.read_text())["warnings"]
    assert "too thin" in capsys.readouterr().err
    # The default S takes the near-white halo too: its 3 px ring lies where the highlight
    # still shapes the shading, and sigma and F_tilde come within 5%.
    assert main([*argv, "--albedo", "uniform"]) == 0
    result = json.loads(out.read_text())
    assert result["sigma"] == pytest.approx(truth["sigma"], rel=0.05)
    np.testing.assert_allclose(result["F_tilde"], truth["F_tilde"], rtol=0.05)


@pytest.mark.parametrize("case", ["no specular pixels", "all saturated", "nan depth"])
def test_fit_bad_input_is_one_clear_error(tmp_path, capsys, case):
    small = dict(width=64, height=48, frames=2, texture=False)
    if case == "no specular pixels":
        root = synthesize(tmp_path / "c", SynthOptions(**small, F_tilde=(0.0, 0.0, 0.0)))
        expected = "no specular pixels"
    else:
        root = synthesize(tmp_path / "c", SynthOptions(**small))
        for name in ("frame_000", "frame_001"):
            if case == "all saturated":
                import cv2

                # Over-exposed (the red channel clipped everywhere), and not duplicates.
                level = 255 if name == "frame_000" else 200
                image = np.full((48, 64, 3), level, np.uint8)
                image[..., 2] = 255  # OpenCV's BGR: red
                cv2.imwrite(str(root / "images" / f"{name}.png"), image)
                expected = "every pixel is saturated"
            else:
                np.save(root / "depth" / f"{name}.npy", np.full((48, 64), np.nan, np.float32))
                (root / "normals" / f"{name}.npy").unlink()
                expected = "no finite positive depth"
    status, lines = command_error(["fit", str(root), "--json", str(tmp_path / "o.json")], capsys)
    assert status == 2 and len(lines) == 1 and expected in lines[0], lines
    assert not (tmp_path / "o.json").exists()


def test_ring_geometry():
    image = np.full((60, 80, 3), 0.4, np.float32)
    image[28:33, 38:43] = 1.0  # a 5x5 highlight
    valid = np.ones((60, 80), bool)
    valid[:, :10] = False
    sets = specular_sets(image, valid, ring_px=3, min_speck_px=0)
    assert sets.specular.sum() == 25
    rows, cols = np.nonzero(sets.ring)
    distance = np.hypot(np.maximum(np.abs(rows - 30) - 2, 0), np.maximum(np.abs(cols - 40) - 2, 0))
    assert distance.max() <= 3 and distance.min() >= 1
    assert not (sets.ring & sets.specular).any() and not sets.ring[:, :10].any()
    # Specks below min_speck_px are not highlights.
    image[5, 70] = 1.0
    assert not specular_sets(image, ring_px=3, min_speck_px=3).specular[5, 70]


def test_an_albedo_of_zero_is_named_as_such(tmp_path):
    """Black tissue with highlights: rho_tilde is 0, which a wider ring would not change."""
    options = SynthOptions(width=96, height=80, frames=2, texture=False, rho_tilde=(0, 0, 0))
    capture = load_capture(synthesize(tmp_path / "c", options))
    estimate = fit_capture(capture, MaskOptions(ring_px=6), albedo="uniform")
    warnings = " ".join(estimate.warnings)
    assert "rho_tilde[R], rho_tilde[G], rho_tilde[B] cannot be told from 0" in warnings
    assert "too thin" not in warnings


def test_frames_with_few_usable_pixels_are_named(tmp_path):
    capture = load_capture(
        synthesize(tmp_path / "c", SynthOptions(width=96, height=80, frames=2, texture=False))
    )
    depth = np.load(capture.root / "depth" / "frame_001.npy")
    depth[:, 4:] = np.nan  # a sliver of shape left
    np.save(capture.root / "depth" / "frame_001.npy", depth)
    (capture.root / "normals" / "frame_001.npy").unlink()
    estimate = fit_capture(load_capture(capture.root), MaskOptions(ring_px=6), albedo="uniform")
    assert any("frame(s) frame_001 (" in w and "few usable" in w for w in estimate.warnings)
