"""Image effects that depend on where a value was recorded: the frame (auto-exposure) and
the pixel (vignetting), applied through `effect.at(site)` everywhere a model predicts."""

import argparse
import dataclasses
import functools
import json

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import command_error

from ctjax import (
    Camera,
    CtjaxError,
    ShadingModel,
    Status,
    Vec3,
    cook_torrance_brdf,
    render,
    shade,
)
from ctjax.calibration import calibrate_near_light
from ctjax.effects import (
    FrameExposure,
    Gain,
    Knee,
    Site,
    Vignetting,
    image_effect_names,
    image_effects,
)
from ctjax.estimation import fit_capture
from ctjax.evaluation import evaluate, fit_colocated
from ctjax.fitting import fit_model_map, paper_model
from ctjax.heldout import HeldOutTracks, frame_consistency
from ctjax.io import load_capture
from ctjax.lights import ColocatedLight
from ctjax.synth import SynthOptions, synthesize


def _site(u, v, frame):
    return Site((jnp.asarray(u, float), jnp.asarray(v, float)), jnp.asarray(frame))


def test_exposure_is_each_frames_own_and_the_first_is_the_reference():
    effect = FrameExposure(np.log([1.2, 0.5]))
    np.testing.assert_allclose(effect.exposure, [1.0, 1.2, 0.5])
    rgb = jnp.asarray([0.1, 0.2, 0.3])
    for frame, factor in enumerate((1.0, 1.2, 0.5)):
        at = effect.at(_site(3.0, 4.0, frame))
        assert isinstance(at, Gain)
        np.testing.assert_allclose(at(rgb), factor * rgb)
        np.testing.assert_allclose(at.inverse(at(rgb)), rgb)
    with pytest.raises(CtjaxError, match="depends on the frame"):
        effect(rgb)
    with pytest.raises(CtjaxError, match="one value per frame"):
        FrameExposure(np.zeros((2, 2)))


def test_vignetting_is_the_polynomial_in_the_tangent_off_the_axis():
    effect = Vignetting(-0.3, 0.05, (50.0, 40.0), (100.0, 80.0))
    assert float(effect.at(_site(50.0, 40.0, 0)).factor) == pytest.approx(1.0)
    # 0.5 focal lengths right and 0.5 down: r^2 = 0.5.
    r2 = 0.5
    expected = 1 - 0.3 * r2 + 0.05 * r2 * r2
    assert float(effect.at(_site(100.0, 80.0, 3)).factor) == pytest.approx(expected)
    with pytest.raises(CtjaxError, match="depends on the pixel"):
        effect(jnp.ones(3))


def test_the_renderer_applies_each_effect_where_the_pixel_was_recorded():
    """`render(..., frame=f)` is `shade` at every pixel of frame f, vignetting and exposure
    included (the renderer's second program gets the pixel grid and the frame)."""
    camera = Camera(24, 16, 20.0, 20.0, 11.5, 7.5)
    effects = (FrameExposure(np.log([1.3, 0.8])), Vignetting(-0.4, 0.0, (11.5, 7.5), (20.0, 20.0)))
    model = ShadingModel(cook_torrance_brdf(0.8, 0.3, 0.25), ColocatedLight(), effects)
    depth = jnp.full((16, 24), 50.0)
    normals = jnp.broadcast_to(jnp.asarray([0.0, 0.0, -1.0]), (16, 24, 3))
    for frame in (0, 2):
        image = np.asarray(
            render(model.brdf, model.light, camera, normals, depth, effects=effects, frame=frame)
        )
        for v, u in ((0, 0), (7, 11), (15, 23)):
            point = camera.backproject((jnp.asarray(float(u)), jnp.asarray(float(v))), 50.0)
            expected = shade(
                model.brdf,
                model.light,
                point,
                Vec3(0.0, 0.0, -1.0),
                (jnp.asarray(float(u)), jnp.asarray(float(v))),
                effects,
                frame,
            )
            np.testing.assert_allclose(image[v, u], expected, rtol=1e-6)
    corner, centre = image[0, 0].sum(), image[8, 12].sum()
    assert corner < centre  # the rim is darker


@pytest.fixture(scope="module")
def exposed(tmp_path_factory):
    """Textured tissue with auto-exposure (sd 0.1 in log), 5 frames."""
    options = SynthOptions(width=128, height=96, frames=5, seed=3, effects={"frame_exposure": 0.1})
    return load_capture(synthesize(tmp_path_factory.mktemp("exposed") / "c", options))


def test_fit_names_the_frames_an_exposure_change_brightens_and_flags_the_lobe(exposed):
    """`fit` with one exposure (the paper's model, `effects=()`) names the frames brighter
    or darker than the others predict, following their true exposure, and its lobe is no
    measurement; by default the fit then fits a gain per frame instead, and says why."""
    truth = exposed.truth["effects"]["frame_exposure"]["effects[0].log_exposure"]
    chosen = fit_capture(exposed).to_json()
    assert chosen["exposure"]["fitted"] == "per_frame"
    assert chosen["exposure"]["one_exposure"]["status"] == "brightness_off"
    assert "frame_exposure" in chosen["exposure"]["why"]
    np.testing.assert_allclose(chosen["log_exposure"], truth, atol=0.005)
    assert chosen["status"] == "successful" and chosen["brightness_off"] == []
    assert chosen["sigma"] == pytest.approx(exposed.truth["sigma"], rel=0.01)
    truth = np.concatenate([[0.0], truth])
    one = fit_capture(exposed, effects=())
    result = one.to_json()
    log_brightness = np.log([result["frames_brightness"][f.name] for f in exposed.frames])
    # Each frame's against the others' (each point's albedo comes from its other frames).
    others = np.asarray([np.delete(truth, f).mean() for f in range(len(truth))])
    np.testing.assert_allclose(log_brightness, truth - others, atol=0.05)
    off = [f.name for f, g in zip(exposed.frames, log_brightness, strict=True) if abs(g) > 0.1]
    assert off and result["brightness_off"] == off
    # Undone, the lobe comes back to the truth (sigma 0.2, F_tilde 0.3): it had absorbed it.
    undone, f_tilde = result["brightness_undone"], np.asarray(exposed.truth["F_tilde"])
    assert np.max(np.abs(result["F_tilde"] / f_tilde - 1)) > 0.15  # 0.19-0.25 for 0.3
    np.testing.assert_allclose(undone["F_tilde"], f_tilde, rtol=0.1)
    assert undone["sigma"] == pytest.approx(exposed.truth["sigma"], rel=0.03)
    assert undone["rgb_rmse"] < 0.5 * result["rgb_rmse"]
    assert result["status"] == "brightness_off"
    assert any("frame_exposure" in w for w in result["warnings"])
    assert not Status.brightness_off.determined and Status.brightness_off.converged
    # Where the gains cannot be fitted, the flagged fit stands and says why.
    from ctjax.estimation._capture_fit import with_exposure_where_needed

    def failing():
        raise CtjaxError("too few views per frame")

    kept = with_exposure_where_needed(one, failing)
    assert kept is one and kept.status.name == "brightness_off"
    assert kept.details["exposure"]["fitted"] == "one"
    assert "too few views per frame" in kept.warnings[-1]


@pytest.mark.parametrize("exposure", [0.0, 0.1])
def test_the_papers_fit_with_one_albedo_checks_the_frames_brightness_too(tmp_path, exposure):
    """`fit --albedo uniform` (the paper's fit on the rings, the default without poses):
    each frame's brightness on its ring against the fit's prediction follows the true
    exposure about the frames' mean, and a lobe that absorbed it is flagged; without an
    exposure every frame reads 1 and the fit stays `successful`."""
    effects = {"frame_exposure": exposure} if exposure else {}
    options = SynthOptions(width=128, height=96, frames=5, seed=3, texture=False, effects=effects)
    capture = load_capture(synthesize(tmp_path / "c", options))
    result = fit_capture(capture, albedo="uniform").to_json()
    log_brightness = np.log([result["frames_brightness"][f.name] for f in capture.frames])
    if not exposure:
        np.testing.assert_allclose(log_brightness, 0.0, atol=0.005)
        assert result["status"] == "successful" and result["brightness_off"] == []
        assert "brightness_undone" not in result
        return
    truth = capture.truth["effects"]["frame_exposure"]["effects[0].log_exposure"]
    truth = np.concatenate([[0.0], truth])
    # measured: within 0.031 (the lobe and the albedo take part of it)
    np.testing.assert_allclose(log_brightness, truth - truth.mean(), atol=0.04)
    off = [f.name for f, g in zip(capture.frames, log_brightness, strict=True) if abs(g) > 0.1]
    assert off and result["brightness_off"] == off
    assert result["status"] == "brightness_off"
    # Undone, the lobe moves towards the truth (sigma 0.231 -> 0.205, F_tilde 0.16-0.20 ->
    # 0.26-0.27 for 0.2 and 0.3): it had absorbed the exposure.
    undone, f_tilde = result["brightness_undone"], np.asarray(capture.truth["F_tilde"])
    assert np.all(
        np.abs(np.asarray(undone["F_tilde"]) - f_tilde) < np.abs(result["F_tilde"] - f_tilde)
    )
    assert undone["sigma"] == pytest.approx(capture.truth["sigma"], rel=0.05)
    assert any("--albedo map --effects frame_exposure" in w for w in result["warnings"])


def test_fit_fits_each_frames_exposure_in_the_branch_and_bound(exposed, tmp_path, capsys):
    """`fit --effects frame_exposure`: a gain per frame alternated with the branch and bound
    recovers the exposures and the lobe, and its frames then agree in brightness."""
    from ctjax.cli import main

    out = tmp_path / "fit.json"
    assert main(["fit", str(exposed.root), "--json", str(out), "--effects", "frame_exposure"]) == 0
    result = json.loads(out.read_text())
    truth = exposed.truth["effects"]["frame_exposure"]["effects[0].log_exposure"]
    np.testing.assert_allclose(result["log_exposure"], truth, atol=0.005)
    assert result["sigma"] == pytest.approx(exposed.truth["sigma"], rel=0.01)
    np.testing.assert_allclose(result["F_tilde"], exposed.truth["F_tilde"], rtol=0.02)
    assert result["status"] == "successful" and result["brightness_off"] == []
    np.testing.assert_allclose(list(result["frames_brightness"].values()), 1.0, atol=0.005)
    assert result["rgb_rmse"] < 2.5  # 9.4 levels without the exposure
    assert "each frame's exposure over the first's 1.00 1.06" in capsys.readouterr().out
    # Image effects the branch and bound does not fit, and the uniform albedo: refused.
    status, lines = command_error(
        ["fit", str(exposed.root), "--json", str(out), "--effects", "vignetting"], capsys
    )
    assert status == 2 and "invalid choice" in lines[-1]
    argv = ["fit", str(exposed.root), "--json", str(out), "--albedo", "uniform"]
    status, lines = command_error([*argv, "--effects", "frame_exposure"], capsys)
    assert status == 2 and "with the albedo map" in lines[0]
    with pytest.raises(CtjaxError, match="calibrate-light"):
        fit_capture(exposed, effects=("vignetting",))


@pytest.mark.slow
def test_exposures_are_recovered_and_the_heldout_frames_get_their_own(exposed):
    """On textured tissue with auto-exposure (sd 0.1 in log), the map fit on the calibration
    frames recovers their exposures, and judging fits the held-out frames' on them."""
    capture = exposed
    truth = np.asarray(capture.truth["effects"]["frame_exposure"]["effects[0].log_exposure"])
    heldout = HeldOutTracks.split(capture, 3, max_points=3000, heldout_points=3000)
    start = paper_model(1.0, 0.3, 0.2)
    start = ShadingModel(start.brdf, start.light, (FrameExposure(np.zeros(4)),))
    fit = fit_model_map(start, heldout.train, max_steps=40, standard_errors=False)
    calibrated = np.asarray(fit.model.effects[0].log_exposure)
    np.testing.assert_allclose(calibrated[:2], truth[:2], atol=0.01)  # frames 1 and 2
    judged = heldout.judge(fit, noise_floor=False)
    np.testing.assert_allclose(judged.model.effects[0].log_exposure, truth, atol=0.01)
    without = dataclasses.replace(fit.model, effects=())
    assert judged.heldout_rmse < 0.5 * heldout.heldout_rmse(without)
    # The views in radiance (for estimators of a model without effects, the facets): each
    # measurement over its frame's exposure, its weight times the exposure squared.
    undone, plain = heldout.in_radiance(fit.model)
    assert plain.effects == () and undone.nuisance is None
    exposure = np.asarray(judged.model.effects[0].exposure)
    for before, after in ((heldout.train, undone.train), (heldout.test, undone.test)):
        seen = np.asarray(before.weight) > 0
        gain = exposure[np.asarray(before.site.frame)][seen]
        np.testing.assert_allclose(
            np.asarray(after.values)[:, seen], np.asarray(before.values)[:, seen] / gain, rtol=1e-5
        )
        np.testing.assert_allclose(
            np.asarray(after.weight)[seen], np.asarray(before.weight)[seen] * gain**2, rtol=1e-5
        )
    assert heldout.in_radiance(without) == (heldout, without)  # nothing to undo
    # Each frame's brightness against what the others predict: the exposure the model
    # lacks, relative to the frames around it; 1 under the model that has it.
    lacking = frame_consistency(heldout, {"without": without})
    log_gain = np.log(list(lacking["brightness"].values()))
    relative = np.concatenate([[0.0], truth]) - np.mean(np.concatenate([[0.0], truth]))
    assert np.corrcoef(log_gain, relative)[0, 1] > 0.9
    # The two frames furthest from the others' mean (log +0.09 and -0.14; read ~1.3x that:
    # each view against its point's other views, the frame itself not among them).
    assert lacking["brightness_off"] == ["frame_003", "frame_004"]
    having = frame_consistency(heldout, {"with": fit.model})
    np.testing.assert_allclose(list(having["brightness"].values()), 1.0, atol=0.03)
    assert having["brightness_off"] == []


def test_image_effects_by_name_start_where_the_diagnostics_would():
    context = dict(frames=4, principal_point=(10.0, 8.0), focal_px=(50.0, 50.0))
    exposure, vignetting = image_effects(("frame_exposure", "vignetting"), paper_model(), context)
    np.testing.assert_array_equal(exposure.log_exposure, np.zeros(3))
    assert isinstance(vignetting, Vignetting) and float(vignetting.k2) == 0.0
    assert "frame_exposure" in image_effect_names() and "inverse_square" not in image_effect_names()
    with pytest.raises(CtjaxError, match="'inverse_square': not an image effect"):
        image_effects(("inverse_square",), paper_model(), {**context, "median_depth_mm": 50.0})
    with pytest.raises(CtjaxError, match="'exposure': unknown; image effects: ambient"):
        image_effects(("exposure",), paper_model(), context)


@pytest.mark.slow
def test_evaluate_fits_the_exposure_in_both_models_and_judges_the_facets_in_radiance(
    exposed, coarse_facets
):
    """`evaluate(effects=...)`: Cook-Torrance's estimator and the Lambertian fit take the
    auto-exposure, each held-out frame's fitted on its views, Lambert under Cook-Torrance's
    light holds Cook-Torrance's; the facets are judged on the views with it undone."""
    truth = np.asarray(exposed.truth["effects"]["frame_exposure"]["effects[0].log_exposure"])
    near = functools.partial(calibrate_near_light, falloff=[()], max_samples=3000)
    said = []
    summary = evaluate(
        exposed, calibration=3, cook_torrance=near, sfs=False, facets=True,
        effects=("frame_exposure",), progress=said.append,
    ).to_json()  # fmt: skip
    # The near light's own steps (minutes on a real capture), under evaluate's.
    fitting = said.index(next(m for m in said if m.startswith("fitting Cook-Torrance")))
    assert said[fitting + 1].startswith("  tracking surface points")
    assert any(m.startswith("  fitting the light's offset with 1 falloff set") for m in said)
    cook_torrance = summary["models"]["cook_torrance"]
    # Fitted on the calibration frames alone: theirs (frames 1 and 2; frame 0 is the
    # reference), the test frames' at their start (each fitted on its own views when judged).
    exposures = np.asarray(cook_torrance["effects"]["log_exposure"])
    np.testing.assert_allclose(exposures[:2], truth[:2], atol=0.01)
    np.testing.assert_array_equal(exposures[2:], 0.0)
    assert cook_torrance["sigma"] == pytest.approx(0.2, rel=0.1)
    # Noise of 1 level: what is left is about it, for the lobe and for neither Lambertian.
    assert summary["cook_torrance_rgb_rmse_test"] < 2.5
    same_light = summary["lambertian_same_light_rgb_rmse_test"]
    assert same_light > 2 * summary["cook_torrance_rgb_rmse_test"]
    # Lambert under Cook-Torrance's light has its exposures too, held as the light is: the
    # two models differ by the lobe alone.
    held = summary["models"]["lambertian_same_light"]["log_exposure"]
    np.testing.assert_array_equal(held, cook_torrance["effects"]["log_exposure"])
    assert summary["facets"]["effects_undone"] == ["FrameExposure"]
    assert summary["frames_rmse"]["brightness_off"] == []
    assert np.isfinite(summary["facets"]["ratio"])
    with pytest.raises(CtjaxError, match="judged with the albedo map"):
        evaluate(exposed, albedo="uniform", effects=("frame_exposure",))
    with pytest.raises(CtjaxError, match="fits no image effects"):
        evaluate(exposed, cook_torrance=fit_colocated, sfs=False, effects=("frame_exposure",))


@pytest.mark.slow
def test_the_near_lights_lobe_that_absorbs_the_exposure_is_flagged(exposed):
    """`calibrate_near_light` without the exposure: the frames' brightness names it, and
    the model refitted with it undone moves its lobe towards the truth: no measurement.
    (The exposure also drew the light ~18 mm off the lens here: F_tilde 0.04-0.05.)"""
    fit = calibrate_near_light(exposed, calibration=3, falloff=[()], max_samples=3000)
    assert fit.status.name == "brightness_off" and fit.details["brightness_off"]
    undone, f_tilde = fit.details["brightness_undone"], np.asarray(exposed.truth["F_tilde"])
    error = lambda f: np.max(np.abs(np.asarray(f) / f_tilde - 1))  # noqa: E731
    assert error(undone["F_tilde"]) < 0.5 * error(fit.to_json()["F_tilde"])
    assert undone["sigma"] == pytest.approx(exposed.truth["sigma"], rel=0.05)


@pytest.mark.slow
def test_the_near_light_with_one_albedo_checks_the_calibration_frames_brightness(tmp_path):
    """`calibrate_near_light(albedo="uniform")`: each calibration frame's brightness against
    the model's prediction follows its exposure about the frames' mean; a frame off is
    named and the model refitted with it undone (here the lobe moves by under 10%: a
    warning, measured 8.5%)."""
    options = SynthOptions(
        width=128, height=96, frames=5, seed=3, texture=False, effects={"frame_exposure": 0.2}
    )
    capture = load_capture(synthesize(tmp_path / "c", options))
    fit = calibrate_near_light(capture, albedo="uniform", falloff=())
    truth = capture.truth["effects"]["frame_exposure"]["effects[0].log_exposure"]
    truth = np.concatenate([[0.0], truth])[:3]  # the calibration frames'
    brightness = fit.details["frames_brightness"]
    assert list(brightness) == [f.name for f in capture.frames[:3]]
    # measured: within 0.005 (the one albedo takes the mean)
    np.testing.assert_allclose(np.log(list(brightness.values())), truth - truth.mean(), atol=0.01)
    assert fit.details["brightness_off"] == ["frame_001"]  # 1.11x
    undone = fit.details["brightness_undone"]
    np.testing.assert_allclose(undone["F_tilde"], capture.truth["F_tilde"], rtol=0.02)
    assert any("the lobe does not absorb it" in w for w in fit.warnings)
    assert fit.status.name == "successful"


def test_the_commands_take_image_effects_by_name(exposed, tmp_path, capsys):
    """`--effects` reaches `evaluate` and `calibrate_near_light` (a name that is not an image
    effect is refused there, before any fit) and is refused where no estimator takes it."""
    json_out = ["--json", str(tmp_path / "out.json")]
    root = str(exposed.root)
    for argv, message in (
        (["evaluate", root, "--effects", "inverse_square"], "not an image effect"),
        (["calibrate-light", root, "--effects", "exposure"], "'exposure': unknown"),
        (["evaluate", root, "--light", "colocated", "--effects", "vignetting"], "--light near"),
        (["calibrate-light", root, "--model", "field", "--effects", "ambient"], "--model near"),
    ):
        status, lines = command_error([*argv, *json_out], capsys)
        assert status == 2 and len(lines) == 1 and message in lines[0], lines


def test_the_commands_print_the_fitted_effects_in_one_line():
    from ctjax._commands._args import effects_line

    effects = (FrameExposure(np.log([1.1, 0.8])), Vignetting(-0.3, 0.05, (5.0, 4.0), (9.0, 9.0)))
    model = ShadingModel(paper_model().brdf, ColocatedLight(), effects)
    assert effects_line(model) == (
        "image effects: each frame's exposure over the first's 1.00 1.10 0.80; "
        "vignetting_k2 -0.3; vignetting_k4 0.05"
    )
    assert effects_line(paper_model()) is None


@pytest.mark.slow
def test_the_held_out_frames_exposures_flag_nothing_with_one_albedo(tmp_path):
    """With one albedo (pixels), the standard errors come from the calibration frames, which
    do not see a held-out frame's exposure: a per-frame nuisance, it flags nothing (it is
    fitted on its frame when judged), and the rest is recovered."""
    options = SynthOptions(
        width=128, height=96, frames=5, seed=3, texture=False, effects={"frame_exposure": 0.1}
    )
    capture = load_capture(synthesize(tmp_path / "c", options))
    truth = np.asarray(capture.truth["effects"]["frame_exposure"]["effects[0].log_exposure"])
    fit = calibrate_near_light(
        capture, calibration=3, falloff=[()], albedo="uniform", effects=("frame_exposure",)
    )
    assert fit.status.name == "successful", fit.details.get("undetermined")
    np.testing.assert_allclose(fit.model.effects[0].log_exposure, truth, atol=0.01)
    stderr = fit.details["stderr"]["effects[0].log_exposure"]
    assert stderr[-1] is None or not np.isfinite(stderr[-1])  # the held-out frame's


def test_the_knee_compresses_each_channel_above_it_and_is_undone():
    effect = Knee(0.6, (0.5, 0.8, 1.0))
    rgb = jnp.asarray([0.9, 0.9, 0.9])
    # Above the knee each channel rises slope times as fast; below it nothing changes.
    np.testing.assert_allclose(effect(rgb), [0.75, 0.84, 0.9])
    np.testing.assert_allclose(effect(jnp.asarray([0.3, 0.5, 0.6])), [0.3, 0.5, 0.6])
    np.testing.assert_allclose(effect.inverse(effect(rgb)), rgb)
    with pytest.raises(CtjaxError, match=r"Knee.slope must be in \(0, 1\]"):
        Knee(0.6, (0.5, 0.0, 1.0))
    with pytest.raises(CtjaxError, match=r"Knee.knee must be in \(0, 1\]"):
        Knee(1.5, 0.5)
    assert "knee" in image_effect_names()
    # Only the channels it compresses: the others rise as the radiance, whatever their slope.
    red = Knee(0.6, (0.5, 0.8, 1.0), compressed=(True, False, False))
    np.testing.assert_allclose(red(rgb), [0.75, 0.9, 0.9])
    np.testing.assert_allclose(red.inverse(red(rgb)), rgb)
    with pytest.raises(CtjaxError, match=r"Knee\.compressed must name the channels"):
        Knee(0.6, 0.5, compressed=(False, False, False))
    # Started for what `load_capture` found: the candidate's start, in those channels only.
    from ctjax.effects._knee import knee_of
    from ctjax.io._channel_ceiling import ChannelKnee

    found = (ChannelKnee(0, 162.0, 1.68, 0.53, 255),)
    started = knee_of(argparse.Namespace(knees=found, encoding="srgb"))
    assert started.compressed == (True, False, False) and float(started.knee) == 0.5
    np.testing.assert_allclose(started.slope, [0.5, 1.0, 1.0])
    # A fitted knee far below where the frames bend stands in for something else.
    from ctjax._candidate import with_effect
    from ctjax.effects._knee import knee_below_the_bend

    bulge = argparse.Namespace(knees=(ChannelKnee(0, 201.0, 1.34, 0.31, 255),), encoding="srgb")
    low = with_effect(paper_model(), Knee(0.109, (0.72, 1.0, 1.0), (True, False, False)))
    assert "far below where the frames bend (0.584" in knee_below_the_bend(low, bulge)
    high = with_effect(paper_model(), Knee(0.645, (0.22, 1.0, 1.0), (True, False, False)))
    assert knee_below_the_bend(high, bulge) is None
    assert knee_below_the_bend(low, argparse.Namespace(knees=(), encoding="srgb")) is None
    assert knee_of(argparse.Namespace(knees=(), encoding="srgb")) is None
    # `ctjax synth --knee KNEE SLOPE [SLOPE_G SLOPE_B]`
    from ctjax.effects._knee import KneeCandidate

    value = KneeCandidate().synth_value
    assert value(argparse.Namespace(knee=[0.5, 0.3])) == (0.5, (0.3, 0.3, 0.3))
    assert value(argparse.Namespace(knee=[0.5, 0.3, 0.6, 0.9])) == (0.5, (0.3, 0.6, 0.9))
    assert value(argparse.Namespace(knee=None)) is None
    with pytest.raises(CtjaxError, match="--knee: expected KNEE SLOPE"):
        value(argparse.Namespace(knee=[0.5, 0.3, 0.6]))


@pytest.mark.slow
def test_a_knee_the_fit_lacks_takes_the_lobe_from_the_channel_it_compresses(tmp_path):
    """A hidden knee (red's slope 0.3 above 0.5): the near light fitted without it drops
    most of red's lobe (the second sinus video's F_tilde [0, 0.008, 0.010]); with `knee`
    among its effects the knee and the lobe come back (measured: knee 0.500, slopes 0.29,
    0.60, 0.91; F_tilde within 8%, sigma within 1%)."""
    options = SynthOptions(
        width=128, height=96, frames=5, seed=3, effects={"knee": (0.5, (0.3, 0.6, 0.9))}
    )
    capture = load_capture(synthesize(tmp_path / "c", options))
    near = functools.partial(calibrate_near_light, capture, calibration=3, falloff=[()])
    lacking, having = near(max_samples=3000), near(max_samples=3000, effects=("knee",))
    f_tilde = np.asarray(capture.truth["F_tilde"])
    assert lacking.to_json()["F_tilde"][0] < 0.5 * f_tilde[0]
    np.testing.assert_allclose(having.to_json()["F_tilde"], f_tilde, rtol=0.1)
    assert having.to_json()["sigma"] == pytest.approx(capture.truth["sigma"], rel=0.03)
    knee = having.model.effects[-1]
    assert isinstance(knee, Knee) and float(knee.knee) == pytest.approx(0.5, abs=0.02)
    np.testing.assert_allclose(knee.slope, [0.3, 0.6, 0.9], atol=0.05)


def test_undone_values_weigh_a_view_by_its_channels_noise_as_recorded():
    """A knee's red at slope 0.25 above 0.6: a bright view's values undone divide red's
    noise by 0.25, so its weight for judging on them (`in_radiance`) is the harmonic mean of
    the squared slopes, 3 / (16 + 1 + 1); the fits' elimination keeps the arithmetic mean
    (their residuals are the image's). A dark view keeps its weight either way."""
    import types

    from ctjax._candidate import with_effect
    from ctjax.fitting._map_least_squares import _linear

    model = with_effect(paper_model(), Knee(0.6, (0.25, 1.0, 1.0), (True, False, False)))
    values = jnp.asarray([[0.9, 0.3], [0.9, 0.3], [0.9, 0.3]])[:, :, None]  # (C, M, P)
    zeros = jnp.zeros((2, 1))
    samples = types.SimpleNamespace(
        values=values, weight=jnp.ones((2, 1)), channels=3, site=((zeros, zeros), zeros.astype(int))
    )
    linear, harmonic = _linear(model, samples, harmonic=True)
    np.testing.assert_allclose(linear[:, 0, 0], [0.6 + 0.3 / 0.25, 0.9, 0.9])
    np.testing.assert_allclose(harmonic[:, 0], [3 / 18, 1.0])
    np.testing.assert_allclose(_linear(model, samples)[1][:, 0], [(0.0625 + 2) / 3, 1.0])
