"""The facets' width along the sequence: the first and the second half of the calibration
frames beside the even and the odd (`ctjax.fitting._drift`). The marginal choosing them in
one pass on a capture: tests/test_facets.py's marginal test."""

import numpy as np

from ctjax.fitting._drift import FIRST, SECOND, boundary_of, drift_reasons, in_subset
from ctjax.fitting._facet_lobe import FACET_F_TILDES, FacetLobe
from ctjax.fitting._marginal_width import at_the_marginal_width, facet_marginal_line


def test_the_halves_along_the_sequence_split_at_the_middle_calibration_frame():
    """As `benchmarks/facet_splits.py` splits them: the first len // 2 calibration frames,
    then the rest; every frame in exactly one half, the parities as before."""
    calibration = [0, 1, 2, 3, 5, 6, 7, 9, 10]  # frames 4 and 8 held out
    boundary = boundary_of(calibration)
    frames = np.arange(12)
    first, second = in_subset(FIRST, frames, boundary), in_subset(SECOND, frames, boundary)
    assert boundary == 5 and not (first & second).any() and (first | second).all()
    assert [f for f in calibration if first[f]] == calibration[: len(calibration) // 2]
    assert in_subset(None, frames, boundary).all()
    np.testing.assert_array_equal(in_subset(1, frames, boundary), frames % 2 == 1)
    assert boundary_of([]) == 0


def test_a_width_that_changes_along_the_sequence_is_unstable():
    """SCARED's frames 61-84 (the facets integrated out): 0.150 on all 15 calibration
    frames, 0.130 / 0.111 on the first / second half, 16% apart, their geometric mean 19.7%
    under the whole's: within the 20% (borderline). A synthetic rigid scene: 0.058 and
    0.0631 / 0.0593. Halves apart, or agreeing away from the whole, are named."""
    assert drift_reasons(0.150, ((0.130, 0.07), (0.111, 0.07))) == []
    assert drift_reasons(0.058, ((0.0631, 0.01), (0.0593, 0.01))) == []
    (apart,) = drift_reasons(0.150, ((0.175, 0.07), (0.111, 0.07)))
    assert apart["parameter"] == "sigma" and apart["status"] == "unstable"
    assert "first and the second half" in apart["reason"] and "45% apart" in apart["reason"]
    (shifted,) = drift_reasons(0.150, ((0.110, 0.07), (0.105, 0.07)))
    assert "together 28% below it" in shifted["reason"]
    assert drift_reasons(0.150, None) == [] and drift_reasons(0.150, ((0.0, 0), (0.1, 0))) == []


def test_the_lobe_at_the_marginals_width_takes_the_drift_and_the_line_shows_it():
    """A width that changes along the sequence is a reason about the width: the facet lobe
    held at it carries it, and the marginal's line prints the halves along the sequence."""
    grid = {(0.15, f): 10.0 for f in FACET_F_TILDES}
    lobe = FacetLobe(0.15, 0.035, grid, False, 9.4, 12.5, 12.0, 0.3, halves=((0.15, 0.032),) * 2)
    (drift,) = drift_reasons(0.150, ((0.110, 0.07), (0.105, 0.07)))
    halves = {
        "even_frames": {"sigma": 0.175, "F_tilde": 0.2},
        "odd_frames": {"sigma": 0.176, "F_tilde": 0.2},
    }
    along = {
        "first_half": {"sigma": 0.110, "F_tilde": 0.07},
        "second_half": {"sigma": 0.105, "F_tilde": 0.07},
    }
    marginal = {"sigma": 0.15, "F_tilde": 0.07, "facet_prior_sigma": 0.7, "noise_levels": 4.0,
                "gain_nats_per_value": 0.1, "halves": halves, "contiguous_halves": along,
                "status": "unstable", "undetermined": [drift]}  # fmt: skip
    found = at_the_marginal_width(lobe, marginal)
    assert found["status"] == "unstable" and found["undetermined"] == [drift]
    assert found["sigma_contiguous_halves"] == [0.110, 0.105]
    line = facet_marginal_line(marginal)
    assert "sigma 0.11 / 0.105 (first / second half)" in line and "first and the second" in line
