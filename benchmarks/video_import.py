"""`ctjax import` on one minute of 1080p video: time and frames kept.

    .venv/bin/python benchmarks/video_import.py [--seconds 60] [--fps 30] [--width 1920]

Writes an MPEG-4 video of a camera panning over a real-like liver scene
(`ctjax.synth.real_like_frame`, larger than the frame), still for a second every few
seconds, with a motion-blurred frame now and then; then times `import_video` with the
default options. The acceptance is under a minute for a minute of 1080p on 2 cores. One
JSON line.
"""

import argparse
import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from _results import emit

from ctjax.io._video import import_video
from ctjax.synth import real_like_frame


def write_video(path: Path, seconds: float, fps: int, width: int) -> int:
    height = width * 9 // 16
    scene = real_like_frame("liver", int(width * 1.5), int(height * 1.5), seed=4).image
    scene = np.round(scene[..., ::-1] * 255).astype(np.uint8)  # BGR
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    count = round(seconds * fps)
    span_x, span_y = scene.shape[1] - width, scene.shape[0] - height
    for k in range(count):
        t = k / fps
        moving = (t % 4) >= 1  # still for the first second of every four
        phase = (t - (t // 4 + 1)) if moving else (t // 4) * 3
        x = int(span_x * (0.5 + 0.5 * np.sin(0.3 * phase)))
        y = int(span_y * (0.5 + 0.5 * np.sin(0.21 * phase + 1)))
        image = scene[y : y + height, x : x + width]
        if k % 97 == 50:
            image = cv2.blur(image, (25, 1))
        writer.write(np.ascontiguousarray(image))
    writer.release()
    return count


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--fps", type=int, default=30)
    parser.add_argument("--width", type=int, default=1920)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        started = time.perf_counter()
        frames = write_video(root / "video.mp4", args.seconds, args.fps, args.width)
        written = time.perf_counter() - started
        height = args.width * 9 // 16
        camera = {"width": args.width, "height": height, "fx": 0.9 * args.width}
        camera |= {"fy": 0.9 * args.width, "cx": args.width / 2, "cy": height / 2}
        (root / "camera.json").write_text(json.dumps(camera))
        started = time.perf_counter()
        report = import_video(root / "video.mp4", root / "camera.json", root / "capture")
        seconds = time.perf_counter() - started
    emit(
        {
            "video_seconds": args.seconds,
            "size": f"{args.width}x{height}",
            "frames": frames,
            "write_seconds": written,
            "import_seconds": seconds,
            **{k: report[k] for k in ("considered", "blurred", "near_duplicates", "kept")},
        }
    )


if __name__ == "__main__":
    main()
