"""Two models compared on the same held-out samples (`ctjax._paired`), and how a diagnosis
reports the candidates its verdict leaves level (`Diagnosis.comparison`)."""

import math

import numpy as np
import pytest

from ctjax._errors import CtjaxError
from ctjax._paired import SampleErrors, paired_difference, z_score


def _errors(squared, frames=4, size=64, count=3.0):
    """Samples on a `size` x `size` pixel grid of `frames` frames, row-major."""
    n = squared.size
    index = np.arange(n)
    frame = index // (size * size) % frames
    row, col = index // size % size, index % size
    return SampleErrors(squared, np.full(n, count), frame, row, col)


def test_the_difference_is_that_of_the_mean_squared_errors_and_its_error_is_the_blocks():
    rng = np.random.default_rng(0)
    n = 4 * 64 * 64
    a = _errors(rng.chisquare(3, n))
    b = _errors(a.squared + 0.3 + 0.1 * rng.standard_normal(n))
    difference, error = paired_difference(a, b)
    assert difference == pytest.approx(a.rmse**2 - b.rmse**2, rel=1e-12)
    # 64 blocks of 16 x 16 px: the standard error of a mean over blocks (each holds 256
    # samples of 3 values), against its direct computation.
    unit = a.blocks()
    assert unit.max() + 1 == 4 * 4 * 4
    per_block = np.bincount(unit, a.squared - b.squared) / np.bincount(unit, a.count)
    expected = np.std(per_block, ddof=1) / math.sqrt(per_block.size)
    assert error == pytest.approx(expected, rel=1e-9)
    assert z_score(difference, error) < -10  # b is worse by 0.1 level^2 a value, everywhere


def test_a_difference_shared_by_neighbours_counts_once_per_block():
    """Errors that move together within a block (what a model misses is smooth) give the
    standard error of the blocks, not of the pixels: a pixel-wise one would be 16x smaller."""
    rng = np.random.default_rng(1)
    frames = 4
    shift = np.repeat(np.repeat(rng.standard_normal((frames, 4, 4)), 16, 1), 16, 2).ravel()
    base = rng.chisquare(3, shift.size) + 10
    a, b = _errors(base + shift), _errors(base)
    difference, error = paired_difference(a, b)
    blocks = shift.reshape(frames, 4, 16, 4, 16).mean(axis=(2, 4)).ravel() / 3
    assert difference == pytest.approx(blocks.mean(), rel=1e-9)
    assert error == pytest.approx(np.std(blocks, ddof=1) / math.sqrt(blocks.size), rel=1e-9)


def test_unequal_judged_samples_and_edge_cases():
    rng = np.random.default_rng(2)
    n = 2 * 64 * 64
    a = _errors(rng.chisquare(3, n))
    counts = a.count.copy()
    counts[::7] = 0  # some samples judged under one model only: each over its own
    b = SampleErrors(np.where(counts > 0, a.squared, 0), counts, a.frame, a.row, a.col)
    difference, error = paired_difference(a, b)
    assert difference == pytest.approx(a.rmse**2 - b.rmse**2, rel=1e-12)
    assert 0 < error < abs(difference) + 1
    # The same errors: no difference, no spread, no z.
    assert paired_difference(a, a) == (0.0, 0.0) and z_score(0.0, 0.0) is None
    # Nothing judged: NaN, and one block: no spread to judge by.
    none = SampleErrors(a.squared, np.zeros(n), a.frame, a.row, a.col)
    assert all(math.isnan(x) for x in paired_difference(none, a))
    one = _errors(np.ones(4), size=2)
    assert paired_difference(one, one)[1] == math.inf
    with pytest.raises(CtjaxError, match="same samples"):
        paired_difference(a, one)


def test_the_comparison_in_words():
    from ctjax.diagnostics import Diagnosis

    leading = {"effect": "spot_falloff", "improvement": 0.0244, "z": 6.3}
    close = [{"effect": "vignetting", "improvement": 0.0241, "z": 0.4}]
    diagnosis = Diagnosis(None, 2.5, [], "none", 1.0, None, [], leading, close)
    first, second = diagnosis.comparison()
    assert first.startswith("leading candidate: spot_falloff") and "6.3 standard errors" in first
    assert "under the 3% a verdict needs" in first
    assert "vignetting (2.4% lower, 0.4 standard errors behind)" in second
    assert "do not tell them apart" in second
    assert diagnosis.verdict_status is None
    named = Diagnosis(None, 2.5, [], "spot_falloff", 1.0, None, [], leading, [])
    assert named.comparison() == [] and named.verdict_status == "determined"
    both = Diagnosis(None, 2.5, [], "spot_falloff", 1.0, None, [], leading, close)
    assert both.verdict_status == "ambiguous"
    # A verdict over the 3% line whose gain the held-out samples do not tell from noise.
    weak = {"effect": "frame_exposure", "improvement": 0.040, "z": 1.18}
    guess = Diagnosis(None, 2.5, [], "frame_exposure", 1.0, None, [], weak, [])
    assert guess.verdict_status == "not_determined"
    (line,) = guess.comparison()
    assert line.startswith("the verdict is not determined: frame_exposure's held-out RMSE")
    assert "4.0% lower, 1.2 standard errors" in line


def test_a_candidate_judged_on_other_samples_is_not_paired():
    """Under one albedo the `albedo_texture` candidate is judged on the map's tracked views,
    the base and the others on pixels: it is not paired with them (on the shared sinus,
    paired on the pixels, the map's model read 10 standard errors behind the base while its
    held-out RMSE was 74% lower on its own samples: `not_determined`, and every other
    candidate "as good")."""
    from ctjax._result import Estimate
    from ctjax.diagnostics import Diagnosis
    from ctjax.diagnostics._compared import compared

    rng = np.random.default_rng(1)
    n = 4 * 64 * 64
    errors = {"base": _errors(rng.chisquare(3, n) + 1.0)}
    errors["spot_falloff"] = _errors(errors["base"].squared - 0.5)
    errors["vignetting"] = _errors(errors["spot_falloff"].squared + rng.normal(0, 0.01, n))

    class Split:  # what `compared` asks of a held-out split
        def heldout_errors(self, model):
            if model == "albedo_texture":
                raise AssertionError("a candidate judged on other samples was paired")
            return errors[model]

    def judged(effect, improvement, **more):
        return Estimate(effect, details={"effect": effect, "improvement": improvement, **more})

    texture = judged("albedo_texture", 0.74, judged_on="map")
    others = [judged("spot_falloff", 0.14), judged("vignetting", 0.12)]
    leading, close = compared(Split(), Estimate("base"), [texture, *others])
    assert leading == {
        "effect": "albedo_texture",
        "improvement": 0.74,
        "z": None,
        "judged_on": "map",
    }
    assert close == []
    diagnosis = Diagnosis(None, 2.5, [], "albedo_texture", 1.0, None, [], leading, close)
    assert diagnosis.verdict_status == "not_paired"
    (line,) = diagnosis.comparison()
    assert line.startswith("the verdict is not paired with the base: albedo_texture")
    assert "74.0% lower" in line and "--albedo map" in line
    # Behind a paired best, it is left out of the candidates compared with it.
    texture.details["improvement"] = 0.01
    leading, close = compared(Split(), Estimate("base"), [*others, texture])
    assert leading["effect"] == "spot_falloff" and leading["z"] > 2
    assert [c["effect"] for c in close] == ["vignetting"] and abs(close[0]["z"]) < 2


def test_no_samples_have_no_errors_and_no_rmse():
    from ctjax._vector import Vec3
    from ctjax.fitting import paper_model, rmse_levels
    from ctjax.fitting._fit import pixel_predict, squared_errors
    from ctjax.observations import PixelSamples

    z, i = np.zeros(0), np.zeros(0, int)
    none = PixelSamples(Vec3(z, z, z), Vec3(z, z, z), (z, z), np.zeros((0, 3)), i, i, i)
    assert squared_errors(paper_model(), none, pixel_predict).shape == (0,)
    assert math.isnan(rmse_levels(paper_model(), none, pixel_predict))
