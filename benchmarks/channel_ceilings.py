"""Where each channel of a capture or a video stops following the others: the evidence for
the ceilings `load_capture` reads as clipped (`ctjax.io._channel_ceiling`).

    .venv/bin/python benchmarks/channel_ceilings.py [SOURCE ...] [--stretch N]

Each SOURCE is a capture folder (its images/) or a video; without SOURCE, the shared real
sequences (`../shared/real`: the sinus frames and the cholecystectomy video). For each,
over all its frames (a video: every 5th) and over every `--stretch` consecutive frames:
per channel, the hinge fitted to the channel's median against the other channels' mean
(the knot's level, the slopes before and after it, codes per code) and the ceiling it
makes, if any; each channel's own pile-up below full scale and the camera's white they
make (two channels or more at one code); and the binned medians themselves, the curve the
hinge is fitted to.

Measured on 2026-12-03: the sinus's red, a knot at 202 of 255 (1.8 codes per code before, 0.18
after; 201-204 on each 7-frame stretch), green and blue none; the cholecystectomy video's
channels none (red 1.2 then 0.8 codes per code, its knot near full scale).
Measured on 2026-12-05: a second sinus video's frames 2739-2834 (24 at 640 px; the sources
in docs/real-video.md), green and blue piling up at 239 of 255, the camera's white from 227
in every channel; its frames 2611-2730 none; the shared sinus's red alone at 225 (no white).
"""

import argparse
from pathlib import Path

import cv2
import numpy as np
from _results import emit

from ctjax.io._channel_ceiling import (
    _pile_up,
    channel_ceilings,
    channel_profile,
    hinge,
    samples_of,
    white_level,
)
from ctjax.io._desaturated import desaturated
from ctjax.io._images import IMAGE_SUFFIXES, read_recorded

SHARED = Path(__file__).resolve().parents[2] / "shared" / "real"
VIDEO_EVERY = 5


def _frames(source: Path) -> list[np.ndarray]:
    """The recorded frames (RGB, uint8 or uint16) of a capture folder or a video."""
    if source.is_dir():
        folder = source / "images"
        paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        return [read_recorded(p) for p in paths]
    video, frames = cv2.VideoCapture(str(source)), []
    while True:
        ok, frame = video.read()
        if not ok:
            return frames[::VIDEO_EVERY]
        frames.append(np.ascontiguousarray(frame[..., ::-1]))


def _figures(frames: list[np.ndarray]) -> dict:
    samples = np.concatenate([samples_of(f, desaturated(f)) for f in frames])
    top = int(np.iinfo(samples.dtype).max)
    out = {
        "samples": len(samples),
        "ceilings": channel_ceilings(samples, top),
        "white_level": white_level(samples, top),
        "channels": {},
    }
    for c, name in enumerate("RGB"):
        centres, medians, weights = channel_profile(samples, top, c)
        fitted = hinge(centres, medians, weights)
        out["channels"][name] = {
            "knot_level": None if fitted is None else round(fitted[1], 1),
            "slope_before": None if fitted is None else round(fitted[2], 3),
            "slope_after": None if fitted is None else round(fitted[3], 3),
            # The channel's own pile-up below full scale (peak, lower edge; 8-bit codes).
            "pile_up": _pile_up(np.round(samples[:, c] / (top / 255))),
            "medians": {int(x): float(m) for x, m in zip(centres, medians, strict=True)},
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sources", nargs="*", type=Path)
    parser.add_argument("--stretch", type=int, default=7, help="frames per stretch (7)")
    args = parser.parse_args()
    sources = args.sources or [SHARED / "jhu-sinus-a", SHARED / "lap-video" / "cholecystectomy.mp4"]
    for source in sources:
        frames = _frames(source)
        whole = _figures(frames)
        stretches = [
            _figures(frames[i : i + args.stretch])["ceilings"]
            for i in range(0, len(frames) - args.stretch + 1, args.stretch)
        ]
        print(f"\n== {source} ({len(frames)} frames, {whole['samples']} samples)")
        for name, channel in whole["channels"].items():
            print(
                f"{name}: knot at {channel['knot_level']}, {channel['slope_before']} then "
                f"{channel['slope_after']} codes per code; pile-up (peak, edge) "
                f"{channel['pile_up']}; medians by the others' mean "
                + " ".join(f"{x}:{m:.0f}" for x, m in channel["medians"].items())
            )
        print(
            f"ceilings {whole['ceilings']} (the camera's white: {whole['white_level']}); per "
            f"{args.stretch}-frame stretch {stretches}"
        )
        emit({"source": str(source), **whole, "stretch": args.stretch, "stretches": stretches})


if __name__ == "__main__":
    main()
