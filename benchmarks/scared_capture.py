"""A real stereo capture (da Vinci Xi, porcine cadaver's abdomen, a moving camera) from the
SCARED subset in FelTris/camp2_3drecon, for the measurements of docs/real-video.md
("A second da Vinci sequence: SCARED").

    .venv/bin/python benchmarks/scared_capture.py CHECKOUT FIRST COUNT OUT [--step K]

CHECKOUT is a checkout (or a bare git directory) of https://github.com/FelTris/camp2_3drecon:
`scared_640/` holds 191 stereo pairs extracted at 5 fps from one SCARED `rgb.mp4` (left and
right JPEGs at 640x512, `left_image/frame_00001.jpg` ...) and `calibration.json` (each
camera's K and five distortion coefficients scaled to them; the pair's R and T in
stereoCalibrate's convention, X_right = R X_left + T, T in mm: a baseline of 4.13 mm). The
repository states no licence and SCARED's own terms restrict redistribution, so neither the
frames nor this capture is part of ctjax. OUT receives the capture format: camera.json (the
k1, k2, p1, p2, k3 keys, its `"stereo"` block, "encoding": "srgb": decoded video), images/
and right/ with the files FIRST, FIRST + K, ... (COUNT of them, their JPEG bytes as stored).
"""

import argparse
import json
import subprocess
from pathlib import Path

_DISTORTION = ("k1", "k2", "p1", "p2", "k3")


def _read(checkout: Path, path: str) -> bytes:
    return subprocess.run(
        ["git", "-C", str(checkout), "show", f"HEAD:scared_640/{path}"],
        capture_output=True,
        check=True,
    ).stdout


def _camera(calibration: dict, side: str) -> dict:
    width, height = calibration["image_size"]
    (fx, _, cx), (_, fy, cy), _ = calibration[side]["K"]
    distortion = dict(zip(_DISTORTION, calibration[side]["distortion"], strict=True))
    return dict(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy, **distortion)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkout", type=Path)
    parser.add_argument("first", type=int)
    parser.add_argument("count", type=int)
    parser.add_argument("out", type=Path)
    parser.add_argument("--step", type=int, default=1)
    args = parser.parse_args()
    calibration = json.loads(_read(args.checkout, "calibration.json"))
    camera = _camera(calibration, "left")
    stereo = calibration["stereo"]
    camera["stereo"] = dict(right=_camera(calibration, "right"), R=stereo["R"], T=stereo["T"])
    camera["encoding"] = "srgb"
    for folder in ("images", "right"):
        (args.out / folder).mkdir(parents=True, exist_ok=True)
    (args.out / "camera.json").write_text(json.dumps(camera, indent=1) + "\n")
    for index in range(args.first, args.first + args.count * args.step, args.step):
        name = f"frame_{index:05d}.jpg"
        for side, folder in (("left_image", "images"), ("right_image", "right")):
            (args.out / folder / name).write_bytes(_read(args.checkout, f"{side}/{name}"))
    print(f"{args.count} pairs from frame {args.first} in {args.out}")


if __name__ == "__main__":
    main()
