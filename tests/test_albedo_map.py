"""The albedo map (textured tissue): the variable projection against a joint solve, its
gradient, truth recovery on textured captures, the command and its errors."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import nnls as scipy_nnls

from ctjax._tracks import views_first
from ctjax.cli import main
from ctjax.estimation import PAPER, fit_capture
from ctjax.estimation._map_fit import fit_albedo_map, summary_stride
from ctjax.estimation._variable_projection import (
    over_views,
    over_views_at_once,
    project_weights,
    projected_residuals,
)
from ctjax.io import load_capture
from ctjax.synth import SynthOptions, synthesize


def _problem(seed, points=7, frames=4, clamp=False):
    """Random positive columns (a diffuse and a specular one) and values of P points."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.1, 0.4, (points, frames))
    b = rng.uniform(0.0, 1.0, (points, frames)) ** 3
    albedo = rng.uniform(0.5, 2.5, (points, 3))
    if clamp:
        albedo[0] = 0.0  # a black point: its least-squares albedo is negative with the noise
    values = a[..., None] * albedo[:, None] + 0.3 * b[..., None]
    values += rng.normal(0, 0.05, values.shape)
    if clamp:
        values[0] -= 0.2
    weight = rng.uniform(0.2, 1.0, (points, frames))
    weight[1, 1:] = 0  # a point observed once
    return a, b, values, weight


def _joint(a, b, values, weight):
    """The same problem as one NNLS over every albedo and F (SciPy), per channel."""
    points, frames = a.shape
    root = np.sqrt(weight).reshape(-1)
    design = np.zeros((points * frames, points + 1))
    for p in range(points):
        design[p * frames : (p + 1) * frames, p] = a[p]
    design[:, points] = b.reshape(-1)
    design *= root[:, None]
    solutions, cost = [], 0.0
    for c in range(3):
        x, residual = scipy_nnls(design, values[..., c].reshape(-1) * root)
        solutions.append(x)
        cost += residual**2
    return np.stack(solutions, -1), cost


@pytest.mark.parametrize("clamp", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_projection_equals_the_joint_nonnegative_least_squares(seed, clamp):
    a, b, values, weight = _problem(seed, clamp=clamp)
    # Views first, points last (`views_first`): columns and weight (M, P), values (C, M, P).
    albedo, weights, cost = jax.jit(project_weights, static_argnums=3)(
        (jnp.asarray(a.T), jnp.asarray(b.T)),
        jnp.asarray(views_first(values)),
        jnp.asarray(weight.T),
        0,
    )
    joint, joint_cost = _joint(a, b, values, weight)
    np.testing.assert_allclose(np.asarray(albedo), joint[:-1], atol=1e-9)
    np.testing.assert_allclose(np.asarray(weights[1]), joint[-1], atol=1e-9)
    assert np.asarray(weights[0]) == pytest.approx(0)  # the per-point lobe's global row
    assert float(cost) == pytest.approx(joint_cost, rel=1e-9)
    if clamp:
        assert np.any(np.asarray(albedo)[0] == 0)
    # float32 takes the cost from the residuals (float64 from the sums): the same solution.
    single = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    albedo, weights, cost = jax.jit(project_weights, static_argnums=3)(
        (single(a.T), single(b.T)), single(views_first(values)), single(weight.T), 0
    )
    assert cost.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(albedo), joint[:-1], atol=2e-5)
    np.testing.assert_allclose(np.asarray(weights[1]), joint[-1], atol=2e-5)
    assert float(cost) == pytest.approx(joint_cost, rel=1e-4)


@pytest.mark.parametrize("over", [over_views, over_views_at_once])
def test_projected_residuals_are_the_joint_fits_either_way_of_summing(over):
    """The LM fitters sum over views at once, the branch and bound by adds of slices
    (faster under `vmap` over sigmas): the same residuals, those of the joint NNLS, and the
    same forward-mode Jacobian."""
    a, b, values, weight = _problem(3, clamp=True)
    columns = (jnp.asarray(a.T), jnp.asarray(b.T))
    measured, observed = jnp.asarray(views_first(values)), jnp.asarray(weight.T)
    residual = jax.jit(lambda s: projected_residuals(columns, measured * s, observed, 0, over)[2])
    joint, _ = _joint(a, b, values, weight)
    predicted = a[..., None] * joint[:-1][:, None] + b[..., None] * joint[-1]
    expected = views_first((values - predicted) * np.sqrt(weight)[..., None])
    np.testing.assert_allclose(np.asarray(residual(1.0)), expected, atol=1e-9)
    slope = jax.jit(jax.jacfwd(residual))(1.0)
    other = over_views_at_once if over is over_views else over_views
    again = jax.jacfwd(lambda s: projected_residuals(columns, measured * s, observed, 0, other)[2])
    np.testing.assert_allclose(np.asarray(slope), np.asarray(jax.jit(again)(1.0)), atol=1e-12)


def test_projected_cost_gradient_matches_finite_differences():
    rng = np.random.default_rng(5)
    points, frames = 20, 5
    normal = rng.normal(size=(points, frames, 3)) * 0.2 + np.array([0, 0, -1.0])
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    view = np.broadcast_to(np.array([0.0, 0.0, -1.0]), normal.shape)
    values = rng.uniform(0.1, 0.8, (points, frames, 3))
    weight = jnp.ones((points, frames))

    @jax.jit
    def cost(sigma):
        brdf = PAPER.build(jnp.atleast_1d(sigma))

        def columns(n, v):
            from ctjax._vector import Vec3

            n, v = Vec3.from_array(n), Vec3.from_array(v)
            return tuple(lobe.radiance(n, v, v) for lobe in brdf.lobes)

        cols = jax.vmap(jax.vmap(columns))(jnp.asarray(normal), jnp.asarray(view))
        cols = tuple(c.T for c in cols)  # views first, points last
        return project_weights(cols, jnp.asarray(views_first(values)), weight.T, 0)[2]

    gradient_of = jax.jit(jax.grad(cost))
    for sigma in (0.15, 0.3):
        gradient = float(gradient_of(sigma))
        step = 1e-6
        finite = (float(cost(sigma + step)) - float(cost(sigma - step))) / (2 * step)
        assert gradient == pytest.approx(finite, rel=1e-5)


@pytest.fixture(scope="module")
def textured(tmp_path_factory):
    """Per-channel textured captures with true depth and poses, 160x128, 6 frames."""
    root = tmp_path_factory.mktemp("albedo")
    return {
        (seed, contrast): synthesize(
            root / f"s{seed}-{contrast}",
            SynthOptions(width=160, height=128, frames=6, seed=seed, texture_contrast=contrast),
        )
        for seed, contrast in ((1, 1.0), (2, 0.5))
    }


def _map_errors(root, estimate):
    capture = load_capture(root)
    errors, coverage = [], []
    for frame in capture.frames:
        estimated = estimate.arrays[f"albedo/{frame.name}"]
        truth = np.load(root / "albedo" / f"{frame.name}.npy")
        assert estimated.shape == truth.shape and estimated.dtype == np.float32
        surface = np.all(np.isfinite(truth), -1)
        both = surface & np.all(np.isfinite(estimated), -1)
        coverage.append(both.sum() / surface.sum())
        errors.append(np.abs(estimated[both] / truth[both] - 1).ravel())
    return np.concatenate(errors), min(coverage)


@pytest.mark.parametrize("key", [(1, 1.0), pytest.param((2, 0.5), marks=pytest.mark.slow)])
def test_the_map_recovers_the_brdf_and_the_texture(textured, key):
    root = textured[key]
    capture = load_capture(root)
    truth = capture.truth
    estimate = fit_capture(capture)  # several frames with depth and poses: the map
    result = estimate.to_json()
    assert result["albedo"] == "map"
    assert result["sigma"] == pytest.approx(truth["sigma"], rel=0.02)
    np.testing.assert_allclose(result["F_tilde"], truth["F_tilde"], rtol=0.03)
    # Over every observation, texture interpolated across frames included.
    assert result["rgb_rmse_calibration"] < 3.0
    # Every frame as bright as the others predict under the fit (no exposure change).
    brightness = list(result["frames_brightness"].values())
    assert len(brightness) == len(capture) and result["brightness_off"] == []
    np.testing.assert_allclose(brightness, 1.0, atol=0.01)
    assert result["status"] == "successful"
    errors, coverage = _map_errors(root, estimate)
    # 160x128 makes the synthetic texture finer than a pixel: looser than at 320x256.
    assert np.median(errors) < 0.015 and np.percentile(errors, 90) < 0.05
    assert coverage > 0.95
    # The paper's uniform albedo on the same textured capture is far off.
    uniform = fit_capture(capture, albedo="uniform").to_json()
    assert uniform["albedo"] == "uniform"
    assert abs(uniform["sigma"] / truth["sigma"] - 1) > 3 * abs(
        result["sigma"] / truth["sigma"] - 1
    )


def test_fit_command_writes_the_albedo_maps(textured, tmp_path, capsys):
    root = textured[(1, 1.0)]
    out, maps = tmp_path / "fit.json", tmp_path / "maps"
    assert main(["fit", str(root), "--json", str(out), "--albedo-maps", str(maps)]) == 0
    result = json.loads(out.read_text())
    assert result["albedo"] == "map" and len(result["rho_tilde"]) == 3
    capture = load_capture(root)
    for frame in capture.frames:
        albedo = np.load(maps / f"{frame.name}.npy")
        assert albedo.shape == (*frame.image.shape[:2], 3) and albedo.dtype == np.float32
        assert np.all(np.isnan(albedo[~frame.geometry_mask]))
    # rho_tilde: the maps' median on every summary_stride-th pixel of every such row.
    read = [np.load(p) for p in maps.iterdir()]
    grid = slice(None, None, summary_stride(capture.camera))
    sparse = np.nanmedian(np.concatenate([m[grid, grid].reshape(-1, 3) for m in read]), 0)
    np.testing.assert_allclose(result["rho_tilde"], sparse, rtol=1e-6)
    whole = np.nanmedian(np.concatenate([m.reshape(-1, 3) for m in read]), 0)
    np.testing.assert_allclose(result["rho_tilde"], whole, rtol=5e-3)
    assert "albedo" in capsys.readouterr().out


def _not_called(*args, **kwargs):
    raise AssertionError("called where the options were to be refused first")


def test_map_without_poses_or_with_uniform_is_one_clear_error(
    textured, tmp_path, capsys, monkeypatch
):
    root = textured[(2, 0.5)]
    out = tmp_path / "fit.json"
    argv = ["fit", str(root), "--json", str(out), "--albedo", "uniform", "--albedo-maps", "m"]
    assert main(argv) == 2
    assert "--albedo-maps needs the albedo map" in capsys.readouterr().err
    assert main([*argv[:6], "--max-tracks", "500"]) == 2
    assert "--max-tracks is for the albedo map" in capsys.readouterr().err
    (root.parent / "nopose").mkdir()
    for item in root.iterdir():
        if item.name != "poses.json":
            (root.parent / "nopose" / item.name).symlink_to(item)
    assert main(["fit", str(root.parent / "nopose"), "--json", str(out), "--albedo", "map"]) == 2
    assert "no pose" in capsys.readouterr().err
    # Without poses the default is the paper's uniform albedo.
    assert main(["fit", str(root.parent / "nopose"), "--json", str(out), "--ring-px", "10"]) == 0
    assert json.loads(out.read_text())["albedo"] == "uniform"
    # The facets refused before any fit (a fit of a 640 px capture takes a minute).
    monkeypatch.setattr("ctjax.estimation._capture_fit.fit_capture", _not_called)
    assert main(["fit", str(root.parent / "nopose"), "--json", str(out), "--facets"]) == 2
    assert "--facets needs the albedo map" in capsys.readouterr().err
    nopose = ["fit", str(root.parent / "nopose"), "--json", str(out), "--facet-marginal"]
    assert main(nopose) == 2
    assert "--facet-marginal needs the albedo map" in capsys.readouterr().err


@pytest.mark.slow
def test_fit_command_caps_the_tracks_and_writes_the_facets(
    textured, tmp_path, capsys, coarse_facets
):
    root = textured[(2, 0.5)]
    out = tmp_path / "fit.json"
    # The tracks' cap: at most that many points followed.
    argv = ["fit", str(root), "--json", str(out), "--max-tracks", "500", "--facets"]
    assert main([*argv, "--facet-marginal"]) == 0
    fitted = json.loads(out.read_text())
    assert 400 < fitted["n_points"] <= 500
    # The lobe about every point's own facet (tests/test_facets.py), beside the fit's, and
    # the facets integrated out.
    assert np.isfinite(fitted["facets"]["heldout_rgb_rmse"])
    # How finely the calibration views sample the lobe, in both blocks (the same tracks).
    step = fitted["facets"]["views_step_rad"]
    assert 0 < step["all_frames"] < step["even_frames"]
    assert step == fitted["facet_marginal"]["views_step_rad"]
    found = fitted["facet_marginal"]
    grid = coarse_facets
    assert min(grid["sigmas"]) <= found["sigma"] <= max(grid["sigmas"])
    assert min(grid["F_tildes"]) <= found["F_tilde"] <= max(grid["F_tildes"])
    assert found["status"] in {"successful", "at_bound", "unstable"}
    # Both: the facet lobe at the marginal's width, its F_tilde chosen by the facet protocol.
    both = fitted["facets_at_the_marginal_width"]
    assert both["sigma"] == pytest.approx(found["sigma"]) and both["sigma_from"] == "facet_marginal"
    assert min(grid["F_tildes"]) <= both["F_tilde"] <= max(grid["F_tildes"])
    assert np.isfinite(both["ratio"]) and both["status"] in {"successful", "at_bound", "unstable"}
    halves = found["halves"]  # None on this capture's few calibration frames
    assert both["sigma_halves"] == (halves and [halves[h]["sigma"] for h in halves])
    printed = capsys.readouterr().out
    assert "a lobe about every point's own facet" in printed
    assert "the facets integrated out" in printed
    assert "the facet lobe at the marginal's width" in printed


def test_a_frame_without_a_pose_falls_back_to_the_uniform_albedo_with_a_warning(tmp_path, capsys):
    """One frame missing from poses.json: the default is still the uniform albedo, but the
    fit (and diagnose) says which frames lack what (a warning on stderr and in the JSON);
    not when the user asked for the uniform albedo, nor when no frame has a pose."""
    from ctjax.estimation import why_no_albedo_map

    root = synthesize(tmp_path / "c", SynthOptions(width=64, height=48, frames=2, seed=3))
    poses = json.loads((root / "poses.json").read_text())
    (root / "poses.json").write_text(json.dumps({"frame_000": poses["frame_000"]}))
    why = why_no_albedo_map(load_capture(root))
    assert "frame(s) frame_001 (no pose): the albedo map follows" in why
    assert "the uniform albedo (the paper's) is fitted instead" in why
    out = tmp_path / "fit.json"
    capsys.readouterr()
    assert main(["fit", str(root), "--json", str(out)]) == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if "frame_001" in line]
    assert warned == [f"ctjax fit: warning: {why}"]
    result = json.loads(out.read_text())
    assert result["albedo"] == "uniform" and result["warnings"][0] == why
    assert main(["fit", str(root), "--json", str(out), "--albedo", "uniform"]) == 0
    assert "frame_001" not in capsys.readouterr().err
    # diagnose says it too (the paper's base and no candidate here: the warning's wiring).
    from ctjax.diagnostics import diagnose

    diagnosis = diagnose(load_capture(root), candidates=(), max_samples=500)
    assert diagnosis.warnings == [why] and diagnosis.to_json()["warnings"] == [why]
    assert diagnose(load_capture(root), candidates=(), albedo="uniform").warnings == []
    (root / "poses.json").unlink()
    assert why_no_albedo_map(load_capture(root)) is None


@pytest.mark.slow
def test_the_lm_fitter_with_the_map_agrees_with_the_branch_and_bound(textured):
    from ctjax.estimation._branch_and_bound_map import fit_brdf_map, track_shading
    from ctjax.fitting import fit_model_map, paper_model
    from ctjax.observations import Observations

    capture = load_capture(textured[(2, 0.5)])
    tracks = Observations.of(capture).tracks(max_points=4000)
    lm = fit_model_map(paper_model(sigma=0.3), tracks)  # LM over sigma alone
    bnb = fit_brdf_map(track_shading(tracks))
    assert lm.converged and lm.details["parameters"] == ["brdf.lobes[1].distribution.sigma"]
    result = lm.to_json()
    assert result["sigma"] == pytest.approx(float(bnb.params[0]), rel=0.005)
    np.testing.assert_allclose(result["F_tilde"], np.asarray(bnb.weights[1]), rtol=0.01)
    np.testing.assert_allclose(result["rho_tilde"], np.asarray(bnb.weights[0]), rtol=0.01)
    assert result["sigma"] == pytest.approx(capture.truth["sigma"], rel=0.02)
    assert lm.arrays["track_albedo"].shape == (len(tracks), 3)


def test_standard_errors_are_the_global_block_of_the_joint_covariance(textured):
    """The map fit's standard errors, with every albedo eliminated (the weights' Jacobian in
    closed form, sigma's by autodiff), are those of the joint Gauss-Newton covariance with
    every free albedo a parameter (a Schur complement), on real tracks."""
    from ctjax.estimation._branch_and_bound_map import (
        _information,
        _standard_errors,
        fit_brdf_map,
        track_columns,
        track_shading,
    )
    from ctjax.estimation._variable_projection import weighted_sums
    from ctjax.observations import Observations

    tracks = Observations.of(load_capture(textured[(1, 1.0)])).tracks(max_points=150)
    shading = track_shading(tracks)
    fit = fit_brdf_map(shading)
    params, weights = fit.params, fit.weights
    free = np.asarray(fit.albedo).T > 0  # (C, P): the albedos not clamped at 0
    n_free = int(free.sum())

    def joint_residuals(theta):
        rho = jnp.zeros(free.shape, theta.dtype).at[free].set(theta[:n_free])
        w = theta[n_free : n_free + 3].reshape(1, 3)  # F_tilde
        s = weighted_sums(
            track_columns(PAPER, theta[n_free + 3 :], shading), shading.values, shading.weight, 0
        )
        return jnp.concatenate(
            [(v - s.a * rho[c] - s.others[0] * w[0, c]).reshape(-1) for c, v in enumerate(s.values)]
        )

    theta = jnp.concatenate([jnp.asarray(fit.albedo).T[free], weights[1], params])
    jacobian = np.asarray(jax.jit(jax.jacfwd(joint_residuals))(theta))  # (eager: 13 s)
    joint = np.linalg.inv(jacobian.T @ jacobian)[n_free:, n_free:]  # F_tilde (3), sigma
    information, scale = jax.jit(_information, static_argnums=(0, 5))(
        PAPER, params, weights, fit.albedo, shading, 0, fit.cost
    )
    np.testing.assert_allclose(np.linalg.inv(np.asarray(information)), joint, rtol=1e-6)
    # And what the fit reports: sqrt(scale * diag(that covariance)).
    sigma_error, weights_error = _standard_errors(information, scale, PAPER.weight_names, 0, 3)
    expected = np.sqrt(float(scale) * np.diagonal(joint))
    np.testing.assert_allclose(np.asarray(fit.params_stderr), expected[3:], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(fit.weights_stderr[1]), expected[:3], rtol=1e-6)
    np.testing.assert_allclose(sigma_error, expected[3:], rtol=1e-6)
    assert np.all(np.isnan(weights_error[0]))  # rho_tilde: per point, no global error


class _Clip(__import__("ctjax").effects.AbstractImageEffect):
    """An image effect without an inverse."""

    def __call__(self, rgb):
        return jnp.minimum(rgb, 0.9)


@pytest.mark.slow
def test_the_lm_fitter_with_the_map_undoes_invertible_image_effects(textured):
    import ctjax
    from ctjax.fitting import fit_model_map, paper_model
    from ctjax.observations import Observations

    tracks = Observations.of(load_capture(textured[(2, 0.5)])).tracks(max_points=500)
    model = paper_model()
    with pytest.raises(ctjax.CtjaxError, match="no inverse"):
        fit_model_map(ctjax.ShadingModel(model.brdf, model.light, (_Clip(),)), tracks)
    # No gamma in the capture: a fitted gamma stays at 1.
    gamma = ctjax.ShadingModel(model.brdf, model.light, (ctjax.CameraGamma(1.5),))
    fit = fit_model_map(gamma, tracks)
    assert fit.converged
    assert float(fit.model.effects[0].gamma) == pytest.approx(1.0, abs=0.05)


@pytest.mark.parametrize(("depth_noise_mm", "tolerance"), [(0.0, 0.01), (0.005, 0.02)])
@pytest.mark.slow
def test_the_map_on_a_capture_from_an_independent_renderer(tmp_path, depth_noise_mm, tolerance):
    """Textured captures from tests/independent.py (plain NumPy, no ctjax code): depth only
    (normals derived on load by a plane fit), exact and with 5 micrometres of depth noise
    (by central differences that noise moved F_tilde by -13% at 320x256)."""
    from independent import Scene, map_errors, render_capture

    scene = Scene()
    albedos = render_capture(
        tmp_path, 160, 128, 6, seed=1, scene=scene, normals=False, depth_noise_mm=depth_noise_mm
    )
    estimate = fit_capture(load_capture(tmp_path))
    result = estimate.to_json()
    assert result["albedo"] == "map"
    assert result["sigma"] == pytest.approx(scene.sigma, rel=tolerance)
    np.testing.assert_allclose(result["F_tilde"], scene.F, rtol=tolerance)
    errors, pixels, channels = map_errors(albedos, estimate)
    assert np.median(errors) < 0.01 and np.percentile(errors, 90) < 0.03
    # Brighter than ctjax's synth: a few % of the pixels clip a channel in every view.
    assert channels > 0.95 and pixels > 0.9


@pytest.mark.parametrize("theta_deg", [5.0, 20.0, 35.0])
def test_the_tilt_changes_the_paper_lobe_as_its_formula_does(theta_deg):
    """`tilted` turns a normal 1 degree away from the half vector: with the light at the
    camera the paper's specular column goes from b(theta) to b(theta + 1 degree), b the
    Beckmann lobe over N.L N.V."""
    from ctjax._vector import Vec3
    from ctjax.estimation._brdf import design_columns
    from ctjax.estimation._sensitivity import tilted
    from ctjax.observations import ShadingSamples

    sigma = 0.25
    theta = np.radians(theta_deg)
    one = lambda x: jnp.asarray([x], jnp.float64)  # noqa: E731
    view = Vec3(one(0.0), one(0.0), one(1.0))
    normal = Vec3(one(np.sin(theta)), one(0.0), one(np.cos(theta)))
    samples = ShadingSamples(normal, view, view, one(1.0), jnp.zeros((1, 3)))

    def specular(angle):
        c = np.cos(angle)
        beckmann = np.exp(-(np.tan(angle) ** 2) / sigma**2) / (sigma**2 * c**4)
        return beckmann / (np.pi * c * c)

    params = jnp.asarray([sigma])
    before = design_columns(PAPER, params, samples)[1]
    after = design_columns(PAPER, params, tilted(samples, 1.0))[1]
    assert float(before[0]) == pytest.approx(specular(theta), rel=1e-9)
    assert float(after[0]) == pytest.approx(specular(theta + np.radians(1.0)), rel=1e-9)


@pytest.mark.slow
def test_the_fit_says_how_much_the_specular_depends_on_the_normals(textured, tmp_path):
    """`details["normals"]`: the fitted specular's change per degree of normal error; a
    shape from `ctjax reconstruct` (its report beside the capture) adds a warning."""
    import shutil

    from ctjax.estimation._map_fit import normals_provenance

    root = textured[(1, 1.0)]
    assert not normals_provenance(load_capture(root))["normals_from_reconstruct"]
    copy = tmp_path / "reconstructed"
    shutil.copytree(root, copy)
    (copy / "reconstruction.json").write_text("{}")
    estimate = fit_capture(load_capture(copy))
    sensitivity = estimate.details["normals"]
    # measured 0.29 at sigma 0.2: -2 tan / (sigma^2 cos^2) + 6 tan, 1 degree, at the rim
    assert 0.1 < sensitivity["specular_change_per_degree"] < 0.6
    # (on every 4th track: 801 observations here)
    assert sensitivity["observations"] > 500 and sensitivity["normals_from_reconstruct"]
    assert any("come from ctjax reconstruct" in w for w in estimate.warnings)
    # Refined by the shading (`reconstruct --shading`): no warning.
    (copy / "reconstruction.json").write_text('{"surface": {"shading": {"refined": true}}}')
    estimate = fit_capture(load_capture(copy))
    assert estimate.details["normals"]["refined_by_the_shading"]
    assert not any("come from ctjax reconstruct" in w for w in estimate.warnings)


@pytest.mark.parametrize("frozen_from", [None, 0])
@pytest.mark.slow
def test_a_held_parameter_stays_at_its_start_and_the_rest_fit_as_if_frozen(
    textured, monkeypatch, frozen_from
):
    """`fit_model_map(hold=...)`: the held parameter keeps its start value (in the same
    compiled program as the fit without it, or, from `FREEZE_HELD_FROM` observations on,
    frozen), the others reach what `freeze` gives."""
    import equinox as eqx

    from ctjax.fitting import _map_least_squares, fit_model_map, paper_model

    if frozen_from is not None:
        monkeypatch.setattr(_map_least_squares, "FREEZE_HELD_FROM", frozen_from)
    from ctjax.lights import PointLight
    from ctjax.observations import Observations

    tracks = Observations.of(load_capture(textured[(2, 0.5)])).tracks(max_points=4000)
    near = eqx.tree_at(lambda m: m.light, paper_model(sigma=0.3), PointLight(jnp.zeros(3)))
    name = "light.position_mm"
    held = fit_model_map(near, tracks, hold=(name,), standard_errors=False)
    frozen = fit_model_map(near, tracks, freeze=(name,), standard_errors=False)
    assert held.converged and held.details["parameters"] == frozen.details["parameters"]
    np.testing.assert_array_equal(np.asarray(held.model.light.position_mm), np.zeros(3))
    assert held.to_json()["sigma"] == pytest.approx(frozen.to_json()["sigma"], rel=1e-6)
    np.testing.assert_allclose(held.to_json()["F_tilde"], frozen.to_json()["F_tilde"], rtol=1e-5)
    # Everything held: the projection is the fit, as with everything frozen.
    sigma = "brdf.lobes[1].distribution.sigma"
    alone = fit_model_map(paper_model(sigma=0.3), tracks, hold=(sigma,), standard_errors=False)
    assert alone.converged and alone.to_json()["sigma"] == pytest.approx(0.3, rel=1e-12)


def test_a_start_given_twice_is_fitted_once(textured, monkeypatch):
    """LM from a start equal to one already run ends where that one did: each distinct
    start runs once (`paper_model`'s sigma 0.2 is one of `ROUGHNESS_STARTS` too)."""
    from ctjax.fitting import _map_least_squares, fit_model_map, paper_model, roughness_variants
    from ctjax.observations import Observations

    tracks = Observations.of(load_capture(textured[(2, 0.5)])).tracks(max_points=4000)
    started = []
    least_squares = _map_least_squares._least_squares

    def counted(start, *args):
        started.append(float(start.brdf.lobes[1].distribution.sigma))
        return least_squares(start, *args)

    monkeypatch.setattr(_map_least_squares, "_least_squares", counted)
    sigma = "brdf.lobes[1].distribution.sigma"
    variants = roughness_variants(paper_model())
    fit = fit_model_map(variants, tracks, hold=(sigma,), standard_errors=False)
    assert len(variants) == 4 and sorted(started) == pytest.approx([0.1, 0.2, 0.35])
    started.clear()
    best = fit_model_map(variants, tracks, hold=(sigma,), refine=2, standard_errors=False)
    assert len(started) in (1, 2) and len(set(started)) == len(started)
    assert best.cost >= fit.cost
    # The LM in float32 (the near light's), the result in the samples' float64.
    single = fit_model_map(
        variants, tracks, hold=(sigma,), standard_errors=False, dtype=jnp.float32
    )
    assert single.cost == pytest.approx(fit.cost, rel=1e-5)
    assert single.model.brdf.weights.dtype == jnp.float64
    assert single.arrays["track_albedo"].dtype == np.float64


@pytest.mark.slow
def test_the_maps_do_not_depend_on_how_the_pixels_are_batched(tmp_path, monkeypatch):
    # Frames are estimated in batches of at most `_MAP_CHUNK` pixels: a frame split into
    # pieces, and pieces of several frames in one batch, give the same maps and summary.
    from ctjax import BRDF, Beckmann, Lambertian, Specular
    from ctjax.estimation import _dense_maps

    root = synthesize(tmp_path / "c", SynthOptions(width=64, height=48, frames=3, seed=4))
    capture = load_capture(root)
    brdf = BRDF(Lambertian(1.0), Specular(0.3, Beckmann(0.2)))

    def estimate():
        maps, views = _dense_maps.albedo_maps(capture, brdf)
        samples = _dense_maps.albedo_samples(capture, brdf, stride=5)
        return maps, views, samples

    whole = estimate()  # the maps one frame per batch, the summary (~130 pixels each) in one
    for chunk in (700, 150):  # the maps in pieces; the summary's frames one per batch
        monkeypatch.setattr(_dense_maps, "_MAP_CHUNK", chunk)
        pieces = estimate()
        for a, b in zip(whole[0] + whole[1], pieces[0] + pieces[1], strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
        for (a, count_a), (b, count_b) in zip(whole[2], pieces[2], strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-10)
            np.testing.assert_array_equal(count_a, count_b)
    assert np.mean(np.isfinite(whole[0][0])) > 0.5  # (the maps are not all NaN)


def _two_view_tracks(tilt_deg: float):
    """One surface point 50 mm ahead seen twice under the paper's light (at the lens), the
    same 0.5 recorded in both views; its normal faces the lens in the first view and is
    tilted by `tilt_deg` in the second (as a wrong light or normal would make it)."""
    from ctjax._tracks import Tracks

    tilt = np.radians(tilt_deg)
    normals = np.array([[0.0, 0.0, -1.0], [np.sin(tilt), 0.0, -np.cos(tilt)]])
    return Tracks(
        corner_point=np.tile([0.0, 0.0, 50.0], (1, 2, 4, 1)),
        corner_normal=np.repeat(normals[None, :, None, :], 4, axis=2),
        corner_pixel=np.full((1, 2, 4, 2), 64.0),
        corner_weight=np.tile([1.0, 0.0, 0.0, 0.0], (1, 2, 1)),
        values=np.full((1, 2, 3), 0.5),
        observed=np.ones((1, 2), bool),
        weight=np.ones((1, 2)),
        frame=np.array([[0, 1]]),
        anchor_frame=np.array([0]),
        anchor_row=np.array([64]),
        anchor_col=np.array([64]),
    )


def test_a_held_out_view_is_judged_only_where_its_other_views_inform_the_albedo():
    """A held-out view is predicted with its point's albedo from the point's other views; a
    view the model calls a hundred times dimmer there gives an albedo a hundred times too
    large, and one such view decided a falloff on real frames (`OTHER_VIEWS_SHARE`). It is
    not judged; a view whose other views are lit half as much is."""
    from ctjax._model import paper_model
    from ctjax.fitting._map_least_squares import TrackSamples, heldout_map_rmse

    model = paper_model(1.0, 0.0, 0.3)  # Lambertian at the lens: shading = N.L / pi
    judged = np.array([[True], [False]])  # the first view judged, from the second
    half = TrackSamples.of(_two_view_tracks(60.0), pad=False)  # N.L 0.5 in the other view
    rmse = heldout_map_rmse(model, half, judged)
    assert rmse == pytest.approx(255 * 0.5, rel=1e-3)  # predicted 1.0: the albedo doubled
    dark = TrackSamples.of(_two_view_tracks(89.4), pad=False)  # N.L 0.01: 100x dimmer
    assert np.isnan(heldout_map_rmse(model, dark, judged))  # nothing judged, not ~12600


def test_a_parameter_the_data_leave_alone_does_not_hide_the_others_standard_errors():
    """sigma where every F_tilde is 0 has a zero Jacobian column: its standard error is
    undetermined (inf), the others' are the rest's block of the information; a block still
    rank-deficient leaves them all undetermined."""
    from ctjax.fitting._fit import variances as _variances

    information = np.array([[0.0, 0.0, 0.0], [0.0, 4.0, 1.0], [0.0, 1.0, 2.0]])
    variance = _variances(0.5, information)
    assert variance[0] == np.inf
    np.testing.assert_allclose(variance[1:], np.diagonal(0.5 * np.linalg.inv(information[1:, 1:])))
    degenerate = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    assert np.all(_variances(0.5, degenerate) == np.inf)
    assert _variances(0.5, np.zeros((0, 0))).shape == (0,)


@pytest.mark.slow
def test_a_frame_sharing_no_point_is_named_and_its_half_not_fitted(textured):
    """Frame 1's depth a million times too far (a corrupt map): its points meet no other
    frame's, so it adds nothing; the odd frames alone (1 and 3) cannot be fitted. The fit
    of the rest stands, with a warning naming the frame and one that the halves were not
    compared (it failed on the halves' fit before, naming no frame)."""
    capture = load_capture(textured[(1, 1.0)])
    frames = list(capture.frames[:4])
    frames[1] = dataclasses.replace(frames[1], depth=1e6 * frames[1].depth)
    estimate = fit_albedo_map(dataclasses.replace(capture, frames=tuple(frames)))
    assert any(w.startswith("frame_001 share(s) no surface point") for w in estimate.warnings)
    assert any(
        "stability across frame subsets is not checked: the odd frames" in w
        for w in estimate.warnings
    )
    assert "halves" not in estimate.details


@pytest.mark.parametrize("dtype", [None, jnp.float32])
@pytest.mark.slow
def test_the_best_start_of_another_structure_is_reported_as_itself(textured, dtype):
    """Starts may differ in static structure (Schlick's Fresnel at V.H or N.V, the
    fresnel_schlick candidate's two): the result is the start that won, in its own
    structure and dtypes, whichever start came first (the shared sinus's diagnose stopped
    here when the N.V start won, the LM in float32)."""
    from ctjax._candidate import with_factor
    from ctjax.fitting import fit_model_map, paper_model
    from ctjax.lobes import SchlickFresnel
    from ctjax.observations import Observations

    tracks = Observations.of(load_capture(textured[(2, 0.5)])).tracks(max_points=2000)
    sigma = "brdf.lobes[1].distribution.sigma"
    far = with_factor(paper_model(sigma=0.95), SchlickFresnel(0.05, "normal"))
    near = with_factor(paper_model(), SchlickFresnel(0.05, "half"))
    fits = [
        fit_model_map(starts, tracks, hold=(sigma,), standard_errors=False, dtype=dtype)
        for starts in ([far], [near], [far, near])
    ]
    assert fits[1].cost < fits[0].cost
    assert fits[2].cost == pytest.approx(fits[1].cost, rel=1e-6)
    fresnel = fits[2].model.brdf.lobes[1].factors[0]
    assert fresnel.cosine == "half"
    assert fits[2].model.brdf.weights.dtype == jnp.float64
    assert jnp.asarray(fresnel.f0).dtype == jnp.float64
