"""Facets: how far does the facet lobe's sigma move between subsets of the calibration
frames, split in different ways?

    python benchmarks/facet_splits.py RECONSTRUCTED_CAPTURE [--random 3] [--marginal]

`ctjax.fitting.facet_lobe` (what `ctjax evaluate --facets` and `fit --facets` report) calls
its lobe `unstable` when the even and the odd calibration frames choose sigmas more than 20%
apart. Each half sees every point's lobe at about twice the angular step of all the frames
(`views_step_rad`), so the halves may disagree for the sampling alone. This chooses sigma
(and F_tilde) on each part of several two-way splits of the calibration frames, the other
part's views weighted 0, under the paper's light (at the lens): even / odd, the first and
the second half (contiguous blocks: the same angular step within a block as all frames,
but different views), and `--random` random splits of the frames into two equal parts.
Prints one JSON line per split: each part's sigma and F_tilde and their spread
(|a - b| / mean, as `ctjax._determined`'s halves check). `--marginal`: the width of the
facets integrated out (`ctjax.fitting.facet_marginal`, `--facet-marginal`'s) instead.

Measured (2026-12-02, the shared sinus, 12 frames at 640 px, `benchmarks/real_video.py`'s
reconstruction; 8 calibration frames; 4:45 on 2 cores): all eight sigma 0.090, F_tilde
0.0167; even / odd 0.094 / 0.069 (30%); first / second half 0.085 / 0.047 (58%); random
0.080 / 0.076 (5.5%), 0.077 / 0.101 (27%), 0.062 / 0.093 (40%): four frames of this
sequence do not determine sigma to 25%, whichever four (docs/real-video.md, "Facets").
SCARED frames 61-84 (`benchmarks/scared_capture.py`, plain `reconstruct`; 15 calibration
frames; 11 min): all 0.103; even / odd 0.134 / 0.123 (8%); first / second half 0.066 / 0.071
(7%); random 9%, 18%, 24% (0.09-0.14): each pair agrees, contiguous frames read half the
width of interleaved ones (the grid's width follows the views' spacing). With `--marginal`
(8 min a split): all 0.150; even / odd 0.175 / 0.176 (1%, F_tilde at the grid's top);
first / second half 0.130 / 0.111 (16%).
`--float64`: as the command line runs (the figures above are float32's). On synthetic truth
(2026-12-03, `facet_truth.py`'s capture at 24 frames, written by `synthesize`; `--float64
--random 1 --marginal`, 14 min; without `--marginal` and `--random 2`, 12 min): the
marginal 0.058 on all, 0.0596 / 0.0603, 0.0631 / 0.0593, 0.0628 / 0.0586 (truth 0.06); the
facet protocol 0.049, 0.055 / 0.053, 0.049 / 0.041, 0.050 / 0.052, 0.056 / 0.052: no shift
between kinds of split on a rigid scene (docs/real-video.md).
"""

import argparse
import json
import time

import equinox as eqx
import jax
import numpy as np

from ctjax.fitting import facet_lobe, facet_marginal
from ctjax.heldout import HeldOutTracks
from ctjax.io import load_capture
from ctjax.lights import ColocatedLight


def _part(train, frames):
    """`train` with the views of frames outside `frames` weighted 0."""
    frame = np.asarray(train.site.frame)
    keep = np.isin(frame, frames) & (frame >= 0)
    weight = np.where(keep, np.asarray(train.weight), 0)
    return eqx.tree_at(lambda s: s.weight, train, weight.astype(np.asarray(train.weight).dtype))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("capture")
    parser.add_argument("--random", type=int, default=3, help="random two-way splits")
    parser.add_argument("--marginal", action="store_true", help="the facets integrated out")
    parser.add_argument("--float64", action="store_true", help="as the command line runs")
    args = parser.parse_args()
    if args.float64:
        jax.config.update("jax_enable_x64", True)
    capture = load_capture(args.capture)
    split = HeldOutTracks.split(capture)
    calib = list(split.calibration)
    rotations = np.stack([np.asarray(f.pose, float)[:3, :3] for f in capture.frames])
    half = len(calib) // 2
    splits = {
        "even / odd": (calib[0::2], calib[1::2]),
        "first / second half": (calib[:half], calib[half:]),
    }
    rng = np.random.default_rng(0)
    for k in range(args.random):
        order = rng.permutation(calib)
        splits[f"random {k}"] = (sorted(order[:half].tolist()), sorted(order[half:].tolist()))
    light = ColocatedLight()

    def chosen(train):
        if args.marginal:
            return facet_marginal(train, rotations, light, halves=False)
        return facet_lobe(train, split.test, split.judged, rotations, light, halves=False)

    started = time.perf_counter()
    whole = chosen(split.train)
    print(
        json.dumps(
            {"split": "all", "frames": calib, "sigma": whole.sigma, "F_tilde": whole.F_tilde}
        )
    )
    for name, parts in splits.items():
        picked = []
        for frames in parts:
            lobe = chosen(_part(split.train, frames))
            picked.append((float(lobe.sigma), float(lobe.F_tilde)))
        (a, fa), (b, fb) = picked
        spread = abs(a - b) / ((a + b) / 2)
        row = {"split": name, "frames": [list(map(int, p)) for p in parts]}
        row |= {"sigma": [a, b], "F_tilde": [fa, fb], "sigma_spread": spread}
        print(json.dumps(row), flush=True)
    print(json.dumps({"seconds": round(time.perf_counter() - started, 1)}))


if __name__ == "__main__":
    main()
