"""A stereo laparoscope's right camera as held-out views: the viewer away from the light's
lens (`shade`'s `eye`), the right views of tracked points (`ctjax.heldout.RightViews`), and
`evaluate`'s report of them."""

import dataclasses
import json
import shutil

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from ctjax import CtjaxError, Vec3, shade
from ctjax.cli import main
from ctjax.estimation import fit_capture
from ctjax.evaluation import evaluate
from ctjax.heldout import RightViews
from ctjax.io import load_capture
from ctjax.lights import InverseSquare, LightField, PointLight
from ctjax.lobes import BRDF
from ctjax.synth import SynthOptions, synthesize
from ctjax.synth._synthesize import scene_model

OPTIONS = SynthOptions(width=160, height=128, frames=4, seed=3, stereo_mm=5.0)


@pytest.fixture(scope="module")
def stereo(tmp_path_factory):
    root = synthesize(tmp_path_factory.mktemp("right") / "c", OPTIONS)
    capture = load_capture(root)
    return capture, RightViews.of(capture)


def _rotation(angles):
    import cv2

    return cv2.Rodrigues(np.asarray(angles, float))[0]


def test_a_viewer_away_from_the_lens_is_the_scene_seen_from_there():
    """Shading in the left camera's frame with the right camera as `eye` is the shading
    in the right camera's frame with the light moved there (synth's right images)."""
    rng = np.random.default_rng(0)
    rotation, translation = _rotation([0.02, -0.05, 0.01]), np.array([-5.0, 0.3, 0.2])
    brdf = scene_model(OPTIONS).brdf
    light = PointLight(jnp.asarray([2.0, -1.0, 0.5]), 1.0, (InverseSquare(70.0),))
    moved = PointLight(jnp.asarray(rotation @ np.asarray(light.position_mm) + translation), 1.0)
    moved = eqx.tree_at(lambda m: m.falloff, moved, light.falloff)
    eye = Vec3.from_array(jnp.asarray(-rotation.T @ translation))
    for _ in range(20):
        point = np.array([*rng.uniform(-15, 15, 2), rng.uniform(50, 90)])
        normal = -point / np.linalg.norm(point) + rng.normal(0, 0.3, 3)
        normal /= np.linalg.norm(normal)
        left = shade(
            brdf, light, Vec3.from_array(point), Vec3.from_array(normal), (0.0, 0.0), eye=eye
        )
        right = shade(
            brdf,
            moved,
            Vec3.from_array(rotation @ point + translation),
            Vec3.from_array(rotation @ normal),
            (0.0, 0.0),
        )
        np.testing.assert_allclose(left, right, rtol=1e-12)
    # The viewer at the lens is the default.
    at_lens = shade(brdf, light, Vec3.from_array(point), Vec3.from_array(normal), (0.0, 0.0))
    origin = Vec3.from_array(jnp.zeros(3))
    np.testing.assert_allclose(
        shade(brdf, light, Vec3.from_array(point), Vec3.from_array(normal), (0.0, 0.0), eye=origin),
        at_lens,
        rtol=1e-14,
    )


def test_the_right_views_judge_the_lobe_by_its_view_direction(stereo):
    """The true model predicts the right views to about the noise; the same model seen from
    the left lens (the right camera's viewpoint ignored), a wrong roughness and no lobe do
    not: the right view moves V and keeps L."""
    _, views = stereo
    model = scene_model(OPTIONS)
    true = views.rmse(model)
    assert true["views"] > 5000 and true["right"] < 2.0 and true["left"] < 2.5
    at_lens = dataclasses.replace(
        views,
        samples=eqx.tree_at(lambda s: s.eye, views.samples, None, is_leaf=lambda x: x is None),
    )
    assert at_lens.rmse(model)["right"] > 1.5 * true["right"]
    rough = eqx.tree_at(lambda m: m.brdf.lobes[1].distribution.sigma, model, jnp.asarray(0.35))
    assert views.rmse(rough)["right"] > 2 * true["right"]
    diffuse = eqx.tree_at(lambda m: m.brdf, model, BRDF(model.brdf.lobes[0]))
    assert views.rmse(diffuse)["right"] > 2 * true["right"]


def test_evaluate_reports_both_models_on_the_right_views(stereo):
    capture, _ = stereo
    evaluation = evaluate(capture, calibration=3, cook_torrance=scene_model(OPTIONS), sfs=False)
    right = evaluation.to_json()["right_views"]
    assert right["frames"] == [0, 1, 2] and right["views"] > 5000
    cook_torrance, lambertian = right["cook_torrance_rgb_rmse"], right["lambertian_rgb_rmse"]
    assert cook_torrance["right"] < 2.0 < 2 * cook_torrance["right"] < lambertian["right"]
    assert "right camera" in right["note"]


def test_right_views_need_a_stereo_capture_in_millimetres(stereo, tmp_path):
    capture, views = stereo
    mono = dataclasses.replace(capture, stereo=None)
    with pytest.raises(CtjaxError, match="no right camera"):
        RightViews.of(mono)
    scaled = dataclasses.replace(capture, length_unit="median_depth")
    with pytest.raises(CtjaxError, match="reconstruct the stereo capture"):
        RightViews.of(scaled)
    with pytest.raises(CtjaxError, match="none given"):
        RightViews.of(capture, [])
    field = LightField(jnp.zeros((capture.camera.height, capture.camera.width, 3)))
    model = eqx.tree_at(lambda m: m.light, scene_model(OPTIONS), field)
    with pytest.raises(CtjaxError, match="light field"):
        views.rmse(model)


@pytest.mark.slow
def test_fit_with_the_right_views_uses_them(stereo, tmp_path):
    """`ctjax fit --right-views`: the right views join the albedo map's tracks (the BnB
    with V towards the right camera and L to the left lens) and the lobe stays the true one."""
    capture, _ = stereo
    out = tmp_path / "fit.json"
    assert main(["fit", str(capture.root), "--right-views", "--json", str(out)]) == 0
    fit = json.loads(out.read_text())
    assert fit["n_right_views"] > 5000 and "right camera" in fit["model"]
    assert fit["sigma"] == pytest.approx(OPTIONS.sigma, rel=0.03)
    np.testing.assert_allclose(fit["F_tilde"], scene_model(OPTIONS).brdf.weights[1], rtol=0.05)


@pytest.mark.parametrize(
    "extra, message",
    [(["--albedo", "uniform"], "albedo map"), ([], "no right camera")],
)
def test_fit_right_views_refused_where_there_are_none(stereo, tmp_path, capsys, extra, message):
    capture, _ = stereo
    root = capture.root
    if not extra:  # a mono copy of the capture
        root = tmp_path / "mono"
        shutil.copytree(capture.root, root, ignore=shutil.ignore_patterns("right"))
        described = json.loads((root / "camera.json").read_text())
        del described["stereo"]
        (root / "camera.json").write_text(json.dumps(described))
    argv = ["fit", str(root), "--right-views", "--json", str(tmp_path / "f.json"), *extra]
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_the_light_field_has_no_right_views(stereo, tmp_path, capsys):
    capture, _ = stereo
    argv = ["calibrate-light", str(capture.root), "--model", "field", "--right-views"]
    assert main([*argv, "--json", str(tmp_path / "l.json")]) == 2
    assert "near light" in capsys.readouterr().err


@pytest.mark.slow
def test_the_near_light_fitted_with_the_right_views(stereo):
    """`calibrate-light --right-views`: the right views join the near light's fits (the
    light at the lens, as synthesised: no offset, the true lobe)."""
    from ctjax.calibration import calibrate_near_light

    capture, _ = stereo
    fit = calibrate_near_light(
        capture, calibration=3, falloff=(), max_samples=4000, heldout_samples=8000, right_views=True
    ).to_json()
    assert fit["n_right_views"] > 5000 and fit["status"] == "successful"
    assert np.linalg.norm(fit["offset_mm"]) < 1.0
    assert fit["sigma"] == pytest.approx(OPTIONS.sigma, rel=0.03)


def test_a_right_view_near_the_highlights_goes_with_its_left_view(stereo):
    """`away_from_highlights` (the light placed on a reconstructed shape): a right view is
    set aside with the same point's left view at the same instant, or where the left camera
    did not see the point then."""
    from ctjax._right_views import with_right_views
    from ctjax.calibration._offset_checks import away_from_highlights
    from ctjax.observations import Observations

    capture, _ = stereo
    observations = Observations.of(capture)
    tracks, right = with_right_views(capture, observations.tracks(max_points=3000))
    placing = away_from_highlights(observations, tracks, right)
    dropped = (tracks.weight > 0) & (placing.weight == 0)
    left = tracks.observed & ~right
    assert dropped[left].any() and dropped[right].any() and not dropped[right].all()
    for index in np.unique(tracks.frame[right]):
        seen = np.any(left & (tracks.frame == index), axis=1)
        close = np.any(dropped & left & (tracks.frame == index), axis=1)
        at = right & (tracks.frame == index) & (tracks.weight > 0)
        points = np.nonzero(at)[0]
        np.testing.assert_array_equal(dropped[at], (close | ~seen)[points])


def test_the_right_views_read_the_right_cameras_ceilings_as_clipped(stereo, tmp_path):
    """A right view whose channel is at or above the right camera's ceiling
    (`Capture.right_saturation`; here camera.json's "ceilings", which both cameras take) is
    not observed, as a left one at the left camera's; the other right views are the same."""
    from ctjax._right_views import right_image, with_right_views
    from ctjax.observations import Observations

    capture, _ = stereo
    assert capture.right_saturation == (1.0, 1.0, 1.0)  # found on its images: none in synth's
    tracks = Observations.of(capture).tracks(max_points=2000)
    plain, right = with_right_views(capture, tracks)
    # Red clipped from its median over the right images' tissue (8-bit linear codes).
    red = np.concatenate([right_image(capture, f.name)[..., 0].ravel() for f in capture.frames])
    code = int(np.median(red[red > 0.02]) * 255)
    root = shutil.copytree(capture.root, tmp_path / "told")
    described = json.loads((root / "camera.json").read_text()) | {"ceilings": [code, None, None]}
    (root / "camera.json").write_text(json.dumps(described))
    told = load_capture(root)
    assert told.right_saturation == told.saturation == pytest.approx(((code - 0.5) / 255, 1, 1))
    clipped, right_told = with_right_views(told, tracks)
    np.testing.assert_array_equal(right_told, right & clipped.observed)
    lost = right & plain.observed & ~clipped.observed
    assert 0 < lost.sum() < (right & plain.observed).sum()
    # Bright in red where they went (a neighbour of the sample at or above the ceiling).
    assert np.median(plain.values[lost][:, 0]) >= (code - 0.5) / 255
    kept = right & clipped.observed
    np.testing.assert_array_equal(plain.values[kept], clipped.values[kept])


def test_a_right_views_excluded_pixels_are_not_observed(stereo, tmp_path):
    """`excluded/right/NAME.png` (an instrument in the right image): the right views landing
    on it are not observed, the others are the same; the left views are untouched."""
    import cv2

    from ctjax._right_views import with_right_views
    from ctjax.observations import Observations

    capture, _ = stereo
    tracks = Observations.of(capture).tracks(max_points=2000)
    plain, right = with_right_views(capture, tracks)
    root = shutil.copytree(capture.root, tmp_path / "masked")
    (root / "excluded" / "right").mkdir(parents=True)
    width = capture.stereo.right.width
    for frame in capture.frames:  # the right image's left half
        mask = np.zeros((capture.stereo.right.height, width), np.uint8)
        mask[:, : width // 2] = 255
        cv2.imwrite(str(root / "excluded" / "right" / f"{frame.name}.png"), mask)
    masked, right_masked = with_right_views(load_capture(root), tracks)
    np.testing.assert_array_equal(right_masked, right & masked.observed)
    left = tracks.observed.shape[1]  # the left views come first, then one right per frame
    np.testing.assert_array_equal(masked.observed[:, :left], plain.observed[:, :left])
    lost = right & ~masked.observed
    assert 0.2 < lost.sum() / right.sum() < 0.8
    kept = right & masked.observed
    np.testing.assert_array_equal(plain.values[kept], masked.values[kept])


@pytest.mark.slow
def test_the_right_views_take_their_instants_exposure(tmp_path):
    """`fit --right-views --effects frame_exposure`: one gain per instant, for both cameras'
    views (the synthetic stereo scope's right images share the left's exposure)."""
    options = SynthOptions(
        width=128, height=96, frames=4, seed=3, stereo_mm=5.0, effects={"frame_exposure": 0.1}
    )
    capture = load_capture(synthesize(tmp_path / "c", options))
    fit = fit_capture(capture, right_views=True, effects=("frame_exposure",)).to_json()
    truth = capture.truth["effects"]["frame_exposure"]["effects[0].log_exposure"]
    assert fit["n_right_views"] > 1000
    np.testing.assert_allclose(fit["log_exposure"], truth, atol=0.01)
    assert fit["sigma"] == pytest.approx(options.sigma, rel=0.03)
    np.testing.assert_allclose(fit["F_tilde"], options.F_tilde, rtol=0.05)
