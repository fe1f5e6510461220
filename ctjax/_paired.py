"""Two models judged on the same held-out samples, compared pair by pair.

A held-out RMSE says how well a model predicts new frames; whether one model predicts them
better than another is a question about the difference of their errors on the same
samples, and how much that difference could move had other samples been drawn. Neighbouring
pixels share what a model misses (a falloff, a missed highlight), so they are not
independent draws: the samples are grouped in blocks of the image (`BLOCK_PX` square, in the
frame where each was seen) and the difference's standard error is taken over the blocks
(the delta method for a ratio of sums, as for any clustered mean).
"""

import dataclasses
import math

import numpy as np

from ._errors import CtjaxError

# Blocks of the image that stand for independent draws (pixels of one frame).
BLOCK_PX = 16


@dataclasses.dataclass(frozen=True)
class SampleErrors:
    """A model's error on each held-out sample: `squared` (N,), its squared residual summed
    over the sample's values (8-bit levels^2); `count` (N,), the values counted (0 where the
    sample is not judged); and where it was seen, `frame`, `row`, `col` (N,) each."""

    squared: np.ndarray
    count: np.ndarray
    frame: np.ndarray
    row: np.ndarray
    col: np.ndarray

    @property
    def rmse(self) -> float:
        """The root-mean-square error (8-bit levels) over every judged value."""
        total = float(np.sum(self.count))
        return math.sqrt(float(np.sum(self.squared)) / total) if total > 0 else math.nan

    def blocks(self, block_px: int = BLOCK_PX) -> np.ndarray:
        """Each sample's block: one index per (frame, row // block_px, col // block_px)."""
        rows = np.floor_divide(np.asarray(self.row, np.int64), block_px)
        cols = np.floor_divide(np.asarray(self.col, np.int64), block_px)
        key = np.stack([np.asarray(self.frame, np.int64), rows, cols], axis=1)
        return np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)


def paired_difference(
    a: SampleErrors, b: SampleErrors, block_px: int = BLOCK_PX
) -> tuple[float, float]:
    """The mean squared error of `a` minus that of `b` (8-bit levels^2), each over the
    samples it judges (the same samples, each model's judged ones), and the difference's
    standard error over the image's blocks (`a`'s places). NaN for both where either judges
    nothing; the standard error is infinite with a single block."""
    if a.squared.shape != b.squared.shape:
        raise CtjaxError(
            f"paired errors must be of the same samples: {a.squared.shape} and {b.squared.shape}"
        )
    unit = a.blocks(block_px)
    sums = [np.bincount(unit, weights=np.asarray(x, float)) for x in (a.squared, a.count)]
    sums += [np.bincount(unit, weights=np.asarray(x, float)) for x in (b.squared, b.count)]
    squared_a, count_a, squared_b, count_b = sums
    total_a, total_b = float(np.sum(count_a)), float(np.sum(count_b))
    if not (total_a > 0 and total_b > 0):
        return math.nan, math.nan
    mse_a, mse_b = float(np.sum(squared_a)) / total_a, float(np.sum(squared_b)) / total_b
    # Each block's share of the difference, linearised about the two means (they sum to 0).
    share = (squared_a - mse_a * count_a) / total_a - (squared_b - mse_b * count_b) / total_b
    used = (count_a > 0) | (count_b > 0)
    k = int(np.sum(used))
    if k < 2:
        return mse_a - mse_b, math.inf
    return mse_a - mse_b, math.sqrt(k / (k - 1) * float(np.sum(share[used] ** 2)))


def z_score(difference: float, standard_error: float) -> float | None:
    """`difference / standard_error`, None where it is not a number (nothing judged, or two
    models whose errors agree on every sample)."""
    if not standard_error > 0 or not math.isfinite(difference):
        return None
    return difference / standard_error
