"""The focal length from the frames (`ctjax reconstruct --focal refine`): where bundle
adjustment takes it from several starts, and SfM's reprojection error with it held.

    python benchmarks/focal_length.py CAPTURE [CAPTURE ...] [--starts 0.5 0.8 1.25]

Each start is a fraction of the image width (fx = fy = start * width); a capture with
truth (a synthetic one) prints its true focal length beside. The refinement is
determined where every start ends at the same focal length (`ctjax.sfm._focal`).
Measured: see `ctjax/sfm/_focal.py`'s module doc.
"""

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from ctjax.io import load_capture
from ctjax.sfm._colmap import sparse_reconstruction


def scan(root: Path, starts, held) -> None:
    capture = load_capture(root)
    width = capture.camera.width
    # A synthetic capture (with truth.json) has the true camera in its camera.json.
    synthetic = (root / "truth.json").is_file()
    truth = json.loads((root / "camera.json").read_text()) if synthetic else None
    print(f"{root} ({width}x{capture.camera.height}, {len(capture)} frames)")
    if truth is not None:
        print(f"  truth: fx {truth['fx']:.1f} px ({truth['fx'] / width:.3f} width)")
    for refine, fractions in ((True, starts), (False, held)):
        for fraction in fractions:
            camera = dataclasses.replace(capture.camera, fx=fraction * width, fy=fraction * width)
            tic = time.perf_counter()
            model = sparse_reconstruction(camera, capture.frames, refine_focal=refine)
            fx, fy = model.focal_px
            print(
                f"  start {fraction:.2f} width, {'refined' if refine else 'held'}: fx, fy "
                f"{fx:.1f}, {fy:.1f} px ({fx / width:.3f} width); registered "
                f"{len(model.registered)}/{len(capture)}, {len(model.points)} points, mean "
                f"reprojection {np.mean(model.point_errors):.4f} px "
                f"({time.perf_counter() - tic:.1f} s)",
                flush=True,
            )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("captures", type=Path, nargs="+")
    parser.add_argument("--starts", type=float, nargs="+", default=[0.5, 0.8, 1.25])
    parser.add_argument(
        "--held", type=float, nargs="*", default=[], help="also SfM with fx held at these"
    )
    args = parser.parse_args(argv)
    for root in args.captures:
        scan(root, args.starts, args.held)


if __name__ == "__main__":
    main()
