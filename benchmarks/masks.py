"""S, S~ and the field of view on real-like 1080p frames: time and the highlight figures.

    .venv/bin/python benchmarks/masks.py [--width 1920] [--runs 5]

For each kind of `ctjax.synth.real_like_frame` (a bright liver frame, a dim one, a
colonoscopy frame with a red channel clipped over the tissue, an octagonal border and a
white icon): the time of what `ctjax masks` does per frame (field of view, white overlays,
S, S~; median and spread of `--runs` runs), the share of the near-white highlight pixels in
S, the share of S within 7 px of the highlights, the pixels of S or S~ outside the field of
view or on the icon, and the paper's HLS rule beside the default. One JSON line per kind.
"""

import argparse
import time

import cv2
import numpy as np
from _results import emit

from ctjax.estimation import HLSThresholds, specular_sets
from ctjax.io import field_of_view, white_overlays
from ctjax.synth import real_like_frame
from ctjax.synth._real_like import KINDS


def masks(image):
    visible = field_of_view(image) & ~white_overlays([image])
    return specular_sets(image, visible=visible), visible


def figures(frame, sets, rule=""):
    near_white = frame.near_white
    highlight = frame.specular >= 0.5 * np.max(frame.image, axis=-1)
    distance = cv2.distanceTransform((~highlight).astype(np.uint8), cv2.DIST_L2, 5)
    specular = sets.specular
    outside = frame.icon | ~frame.inside
    return {
        f"{rule}near_white_in_S": float((specular & near_white).sum() / max(near_white.sum(), 1)),
        f"{rule}S_within_7px": float(np.mean(distance[specular] <= 7)) if specular.any() else None,
        f"{rule}S_or_ring_outside": int(((specular | sets.ring) & outside).sum()),
        f"{rule}ring_pixels": int(sets.ring.sum()),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    height = args.width * 9 // 16
    for kind in KINDS:
        frame = real_like_frame(kind, args.width, height, seed=1)
        masks(frame.image)  # OpenCV's first calls
        seconds = []
        for _ in range(args.runs):
            started = time.perf_counter()
            sets, visible = masks(frame.image)
            seconds.append(time.perf_counter() - started)
        paper = specular_sets(frame.image, visible=visible, highlights=HLSThresholds())
        emit(
            {
                "kind": kind,
                "size": f"{args.width}x{height}",
                "seconds_median": float(np.median(seconds)),
                "seconds_min": float(np.min(seconds)),
                "seconds_max": float(np.max(seconds)),
                "near_white_pixels": int(frame.near_white.sum()),
                **figures(frame, sets),
                **figures(frame, paper, "hls_"),
            }
        )


if __name__ == "__main__":
    main()
