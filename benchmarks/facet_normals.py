"""Facets: does a lobe about each surface point's own facet, read from the views where the
point shone, predict held-out views better than Lambert?

    python benchmarks/facet_normals.py RECONSTRUCTED_CAPTURE [--light near|colocated]
        [--frames all|even|odd] [--control] [--skip-persistence]

Two measurements, each printed as one JSON line.

1. **Do the highlights stay on the same surface points?** (`ctjax.specular.
   highlight_persistence`) Every pixel of S in frame k carried by its depth and the poses
   into frame t; the share landing in t's S against pixels at random, by |k - t|.
2. **A facet per point** (`ctjax.fitting.facet_lobe`, what `ctjax evaluate --facets`
   reports): every tracked point's lobe about its own normal, chosen among no lobe, the
   reconstruction's normal and H of each of its other views; sigma and F_tilde chosen on
   the calibration frames; the held-out views predicted beside Lambert under the same
   light (`--light near`: `calibrate_near_light`'s, for both; `colocated`: the paper's).
   `--control`: the same with every point's candidates another point's.

Measured (2026-11-28, 12 frames at 640 px, `ctjax reconstruct`; near light; the test's
facets turned by two angles): the shared sinus: S lands in S one frame on 0.88 (0.007 at
random); facets sigma 0.1, F_tilde 0.01 (grid), test 17.70 against Lambert's 22.09 levels
(0.801x; Lambert with its own normal chosen the same way 0.925x; control 0.965x); even /
odd frames 0.846x / 0.803x (sigma 0.15 / 0.1). The cholecystectomy video: 0.64 (0.045);
0.990x (control 0.997x). The SurgT da Vinci clip (`reconstruct --stereo pairs`): 0.99
(0.055), its camera barely moving; 0.985x (control 0.983x). docs/real-video.md, "Facets".
Refined between the grid's points (F_tilde 13 values), with the status (the grid again on
the even and the odd calibration frames, 2026-11-28): sinus sigma 0.101 +- 0.006
(bootstrap over the points), F_tilde 0.0106 +- 0.0008, 0.800x, unstable (halves 0.133 /
0.092); its even frames 0.151 +- 0.004, its odd frames 0.087 +- 0.006, both unstable
(4 calibration frames, too few for halves); cholecystectomy no_lobe (gain 0.02%,
1.037x); SurgT at_bound (F_tilde at the grid's top).
With two candidate sets, the better on the calibration views used (the views' H, each
view's own included, or those turned across the views' arc: `FACET_CANDIDATES`), sigma's
grid from 0.025 (2026-11-28, `--control`): sinus the views' H, sigma 0.105 +- 0.003,
F_tilde 0.0089, 0.806x (control 0.967x), unstable (halves 0.112 / 0.079); its even / odd
frames across the arc, 0.122 / 0.068, 0.868x / 0.865x; cholecystectomy no_lobe (0.993x);
SurgT across the arc, at_bound (sigma at the grid's bottom), 0.923x (control 0.979x).
"""

import argparse
import dataclasses
import time
from pathlib import Path

import jax
from _results import emit

from ctjax import ColocatedLight
from ctjax.calibration import calibrate_near_light
from ctjax.fitting._facets import FACET_PENALTY
from ctjax.heldout import HeldOutTracks
from ctjax.io import load_capture
from ctjax.specular import highlight_persistence


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("--light", choices=("near", "colocated"), default="near")
    parser.add_argument("--penalty", type=float, default=FACET_PENALTY)
    parser.add_argument("--frames", choices=("all", "even", "odd"), default="all")
    parser.add_argument("--skip-persistence", action="store_true")
    parser.add_argument(
        "--control", action="store_true", help="also with every point's facets another point's"
    )
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    capture = load_capture(args.capture)
    if args.frames != "all":
        capture = dataclasses.replace(
            capture, frames=capture.frames[0 if args.frames == "even" else 1 :: 2]
        )
    if not args.skip_persistence:
        persistence = highlight_persistence(capture).to_json()
        emit({"capture": str(args.capture), "highlights_stay": persistence})

    started = time.perf_counter()
    tracks = HeldOutTracks.split(capture)
    if args.light == "near":
        calibration = len(tracks.calibration)
        light = calibrate_near_light(tracks.capture, calibration=calibration).model.light
    else:
        light = ColocatedLight()
    row = {"capture": str(args.capture), "frames": args.frames, "light": args.light}
    for name, seed in (("facets", None), ("control", 0))[: 2 if args.control else 1]:
        lobe = tracks.facet_lobe(light, penalty=args.penalty, shuffle_seed=seed)
        out = lobe.to_json()
        out.pop("calibration_rgb_rmse")
        row[name] = out
    row["seconds"] = round(time.perf_counter() - started, 1)
    emit(row)


if __name__ == "__main__":
    main()
