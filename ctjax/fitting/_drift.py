"""The width along the sequence: the first and the second half of the calibration frames.

The even and the odd calibration frames each span the whole stretch, so each carries
whatever changes along it (the tissue breathing or moving under the scope, the shape or the
poses drifting between its ends) and they agree however much that widens the lobe. The
first and the second half (contiguous frames, split at the middle calibration frame) do not:
where a facet seen early sits elsewhere than the same facet seen late, each half reads a
narrower lobe than all the frames together.

Measured with `benchmarks/facet_splits.py --marginal` (docs/real-video.md, "Facets"): on a
synthetic capture with truth and the same camera sweep (24 frames of 256x192, a facet lobe
of 0.06, 15 calibration frames) the facets integrated out read 0.058 on all of them, 0.0596 /
0.0603 on the even / odd frames and 0.0631 / 0.0593 on the first / second half: no shift on
a rigid scene. On SCARED's frames 61-84 (da Vinci, porcine): 0.150 on all, 0.175 / 0.176 even
/ odd, 0.130 / 0.111 first / second half (their geometric mean 20% under the whole's).
"""

import math

from .._determined import HALVES_AGREE, Undetermined
from .._status import Status

FIRST, SECOND = "first", "second"


def in_subset(subset, frame, boundary):
    """Whether views of `frame` belong to `subset`: None every frame, 0 / 1 the even / odd
    frames, `FIRST` / `SECOND` the frames before / from `boundary` (NumPy or JAX)."""
    if subset is None:
        return frame == frame
    if subset == FIRST:
        return frame < boundary
    if subset == SECOND:
        return frame >= boundary
    return frame % 2 == subset


def boundary_of(calibration_frames) -> int:
    """The first frame of the second half: the middle calibration frame (`len // 2`, as
    `benchmarks/facet_splits.py` splits them)."""
    frames = sorted(int(f) for f in calibration_frames)
    return frames[len(frames) // 2] if frames else 0


def drift_reasons(sigma: float, contiguous) -> list[dict]:
    """sigma on the first and the second half of the calibration frames, checked as the
    even and odd halves are (`Undetermined.to_json()`; empty where they agree): apart by more
    than `HALVES_AGREE`, or agreeing on a width more than `HALVES_AGREE` from the whole's
    (geometric mean)."""
    if not contiguous or not sigma > 0:
        return []
    (a, _), (b, _) = contiguous
    if not (a > 0 and b > 0 and math.isfinite(a) and math.isfinite(b)):
        return []
    spread = abs(a - b) / ((a + b) / 2)
    shift = math.sqrt(a * b) / sigma - 1
    if spread > HALVES_AGREE:
        found = f"{spread:.0%} apart"
    elif abs(shift) > HALVES_AGREE:
        found = f"together {abs(shift):.0%} {'above' if shift > 0 else 'below'} it"
    else:
        return []
    return [
        Undetermined(
            "sigma",
            Status.unstable,
            f"the first and the second half of the calibration frames alone put sigma at "
            f"{a:.3g} and {b:.3g} against {sigma:.3g} on all of them ({found}, over "
            f"{HALVES_AGREE:.0%}): the width changes along the sequence (tissue motion, or the "
            "shape or the poses drifting), which the even and odd frames, each spanning it "
            "all, cannot show",
        ).to_json()
    ]
