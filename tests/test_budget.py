"""What is left of a residual: misregistration, highlights, a gain per frame, a trend."""

import dataclasses

import numpy as np
import pytest

from ctjax.diagnostics import residual_budget
from ctjax.estimation import fit_capture
from ctjax.io import load_capture
from ctjax.synth import SynthOptions, synthesize


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A textured capture (128x96 x 5) and the paper's model fitted to it."""
    options = SynthOptions(width=128, height=96, frames=5, seed=1)
    capture = load_capture(synthesize(tmp_path_factory.mktemp("budget") / "c", options))
    return capture, fit_capture(capture).model


def _with_first_frame(capture, image):
    frames = list(capture.frames)
    frames[0] = dataclasses.replace(frames[0], image=image)
    return dataclasses.replace(capture, frames=tuple(frames))


def test_a_shifted_frame_is_read_as_misregistration(fitted):
    """Frame 0's image shifted by one pixel along x against its geometry: the residual grows
    with the texture's gradient, and its slope gives the shift's RMS per axis (1 px along
    one axis of an isotropic texture: sqrt(1/2) = 0.71 px; measured 0.64)."""
    capture, model = fitted
    clean = residual_budget(capture, [0], model)
    shifted = residual_budget(
        _with_first_frame(capture, np.roll(capture.frames[0].image, 1, axis=1)), [0], model
    )
    assert clean.misregistration_px < 0.2  # measured 0.11 (resampling the other frames)
    assert 0.5 < shifted.misregistration_px < 0.85
    assert shifted.gradient_share > 0.4 and shifted.rmse > 2 * clean.rmse
    # Not a gain, not a trend in a physical variable.
    assert shifted.per_frame_share < 0.05 and max(shifted.smooth_share.values()) < 0.05
    assert set(shifted.to_json()["smooth_share"]) >= {"n_dot_v", "radius_px"}
    assert "px of misregistration" in shifted.summary()
    # Where the distance to the light takes most, in the capture's length unit.
    by_distance = shifted.smooth_share | {"light_distance_mm": 0.9}
    relative = dataclasses.replace(shifted, smooth_share=by_distance, length_unit="median_depth")
    assert "(distance to the light (median depths))" in relative.summary()


def test_the_distance_to_the_light_is_named_in_the_captures_length_unit():
    """A budget of a capture reconstructed up to scale names its distance to the light in
    median depths: its lengths are not millimetres."""
    from ctjax.diagnostics._variables import variable_label

    metric = variable_label("light_distance_mm", "mm")
    assert metric == "distance to the light (mm)"
    assert variable_label("light_distance_mm", "median_depth") == (
        "distance to the light (median depths)"
    )
    assert variable_label("radius_px", "median_depth") == "distance from the image centre (px)"


def test_a_frame_brighter_than_the_model_is_a_gain_per_frame(fitted):
    capture, model = fitted
    brighter = _with_first_frame(capture, np.clip(1.15 * capture.frames[0].image, 0, 1))
    budget = residual_budget(brighter, [0, 1], model)
    assert budget.per_frame_share > 0.6
    assert budget.misregistration_px < 0.3


def test_the_heldout_budget_divides_the_diagnosis_rmse(fitted):
    """Under the map the budget is of the held-out views the diagnosis judged: the RMSE it
    divides is the diagnosis's own."""
    from ctjax.diagnostics import diagnose, heldout_budget

    capture, _ = fitted
    diagnosis = diagnose(capture, albedo="map", candidates=(), max_samples=3000)
    budget = heldout_budget(diagnosis.heldout, diagnosis.base.model)
    assert budget.rmse == pytest.approx(diagnosis.base_rmse, rel=1e-6)
    assert budget.misregistration_px < 0.2 and budget.per_frame_share < 0.05
    assert 0 < budget.highlight_pixels < 0.5


def test_a_model_without_the_lobe_leaves_its_error_at_the_highlights(fitted):
    """The Lambertian model on a capture with a specular lobe: what is left lies near S,
    brighter than the model there; not a misregistration, not a gain per frame."""
    from ctjax.estimation import LAMBERTIAN

    capture, model = fitted
    lambertian = fit_capture(capture, family=LAMBERTIAN).model
    frames = [3, 4]
    without, with_lobe = (residual_budget(capture, frames, m) for m in (lambertian, model))
    # measured: 45% of the squared residual on 3% of the pixels, 1.7 levels brighter
    assert without.highlight_share > 0.3 and without.highlight_share > 10 * without.highlight_pixels
    assert without.highlight_excess > 1
    # measured: 2%, +0.1 levels
    assert with_lobe.highlight_share < 0.1 and abs(with_lobe.highlight_excess) < 0.5
    assert with_lobe.rmse < without.rmse
    assert without.misregistration_px < 0.3 and without.per_frame_share < 0.05


def test_a_frame_the_others_do_not_predict_is_named(fitted):
    """Frame 0's image shifted by 3 px against its geometry: its views, each predicted from
    the point's albedo in the other frames, are far worse than the other calibration
    frames' (`HeldOutTracks.frame_rmse`), and `frames_not_predicted` names it; the same
    capture unshifted names none (2.03-2.26 levels in every frame). The calibration
    frames' figures combine, weighted by their views, into the calibration RMSE."""
    from ctjax.fitting._map_least_squares import heldout_map_residuals
    from ctjax.heldout import HeldOutTracks, frame_consistency, frames_not_predicted

    capture, model = fitted
    clean = HeldOutTracks.split(capture)
    rmse = clean.frame_rmse(model)
    assert sorted(rmse) == list(range(len(capture.frames)))
    assert frames_not_predicted(rmse, clean.calibration)[0] == []
    _, weight = heldout_map_residuals(model, clean.train)
    frame = np.asarray(clean.train.site.frame)
    views = [np.sum(weight[(frame == f) & (weight > 0)]) for f in clean.calibration]
    combined = np.sqrt(np.average([rmse[f] ** 2 for f in clean.calibration], weights=views))
    assert combined == pytest.approx(clean.rmse(model)["calibration"], rel=1e-6)
    shifted = _with_first_frame(capture, np.roll(capture.frames[0].image, 3, axis=1))
    split = HeldOutTracks.split(shifted, 4)  # measured 16.7 levels against a median of 8.2
    rmse = split.frame_rmse(model)
    outliers, median = frames_not_predicted(rmse, split.calibration)
    assert outliers == [0] and rmse[0] > 1.8 * median
    block = frame_consistency(split, {"lambertian": model})
    assert block["not_predicted"] == [capture.frames[0].name]
    assert block["lambertian"][capture.frames[0].name] == pytest.approx(rmse[0])


def test_a_frame_whose_depth_disagrees_is_named_not_judged(fitted):
    """A held-out frame whose depth is 1e6 times the others' (a corrupt depth map) has no
    pixel on a point the other frames see: `frame_consistency` names it (evaluate warns),
    where it was a silent null in frames_rmse."""
    from ctjax.heldout import HeldOutTracks, frame_consistency

    capture, model = fitted
    frames = list(capture.frames)
    frames[-1] = dataclasses.replace(frames[-1], depth=1e6 * frames[-1].depth)
    split = HeldOutTracks.split(dataclasses.replace(capture, frames=tuple(frames)), 3)
    block = frame_consistency(split, {"lambertian": model})
    assert block["not_judged"] == [capture.frames[-1].name]
    assert block["lambertian"][capture.frames[-1].name] is None
    assert frame_consistency(HeldOutTracks.split(capture, 3), {"l": model})["not_judged"] == []
