"""Image effects that depend on where a value was recorded: the frame (auto-exposure) and
the pixel (vignetting), applied through `effect.at(site)` everywhere a model predicts."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from ctjax import Camera, CtjaxError, ShadingModel, Vec3, cook_torrance_brdf, render, shade
from ctjax.effects import FrameExposure, Gain, Site, Vignetting
from ctjax.fitting import fit_model_map, paper_model
from ctjax.heldout import HeldOutTracks
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


def test_exposures_are_recovered_and_the_heldout_frames_get_their_own(tmp_path):
    """On textured tissue with auto-exposure (sd 0.1 in log), the map fit on the calibration
    frames recovers their exposures, and judging fits the held-out frames' on them."""
    options = SynthOptions(width=128, height=96, frames=5, seed=3, effects={"frame_exposure": 0.1})
    capture = load_capture(synthesize(tmp_path / "c", options))
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
