"""A real stereo capture (da Vinci, in-vivo porcine abdomen) from the SurgT labelling tool's
sample clip, for `benchmarks/stereo_right_views.py`.

    .venv/bin/python benchmarks/surgt_capture.py SURGT_LABELLING OUT

SURGT_LABELLING is a checkout (or a bare git directory) of
https://github.com/Cartucho/SurgT_labelling (Apache-2.0; the sample was added in commit
35131232, "SurgT (#3)"): `data/video.mp4` holds 10 frames, 2560x1024 at 25 fps, the left
and right views side by side (left: columns 0-1279, as the tool's `code/label.py` splits
them), and `data/calibration.yaml` OpenCV's `M1 D1 M2 D2 R T` (stereoCalibrate's convention,
X_right = R X_left + T; T in mm: a baseline of 4.14 mm). The clip is one of the MICCAI 2022
SurgT challenge's stereo videos (cite Cartucho et al., Medical Image Analysis 91, 102985,
2024); no data licence beyond the repository's is stated, so the frames are not part of
ctjax. OUT receives the capture format: camera.json (its `"stereo"` block; sRGB: decoded
video), images/ and right/ (frame_000.png ...). The camera barely moves over the 0.4 s
(about 27 px), too little parallax for structure-from-motion: the benchmark takes each
frame's depth from its own pair.
"""

import argparse
import json
import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np


def _file(source: Path, path: str, into: Path) -> Path:
    """`path` of a checkout, or of a bare git directory (`git show HEAD:path`)."""
    if (source / path).is_file():
        return source / path
    out = into / Path(path).name
    blob = subprocess.run(
        ["git", f"--git-dir={source}", "show", f"HEAD:{path}"], check=True, capture_output=True
    )
    out.write_bytes(blob.stdout)
    return out


def _camera(storage, matrix: str, distortion: str, width: int, height: int) -> dict:
    k = storage.getNode(matrix).mat().astype(np.float64)
    d = storage.getNode(distortion).mat().astype(np.float64).ravel()
    camera = {"width": width, "height": height}
    camera |= {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2]}
    return camera | dict(zip(("k1", "k2", "p1", "p2", "k3"), d[:5].tolist(), strict=False))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("source", type=Path, help="SurgT_labelling checkout or git directory")
    parser.add_argument("out", type=Path)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as scratch:
        video = _file(args.source, "data/video.mp4", Path(scratch))
        calibration = _file(args.source, "data/calibration.yaml", Path(scratch))
        storage = cv2.FileStorage(str(calibration), cv2.FILE_STORAGE_READ)
        reader = cv2.VideoCapture(str(video))
        frames = []
        while True:
            ok, frame = reader.read()
            if not ok:
                break
            frames.append(frame)
        reader.release()
        if not frames:
            raise SystemExit(f"{video}: no frames read")
        height, width = frames[0].shape[0], frames[0].shape[1] // 2
        left = _camera(storage, "M1", "D1", width, height)
        right = _camera(storage, "M2", "D2", width, height)
        u, _, vt = np.linalg.svd(storage.getNode("R").mat().astype(np.float64))
        translation = storage.getNode("T").mat().astype(np.float64).ravel()
        storage.release()
    for folder in ("images", "right"):
        (args.out / folder).mkdir(parents=True, exist_ok=True)
    for index, frame in enumerate(frames):
        cv2.imwrite(str(args.out / "images" / f"frame_{index:03d}.png"), frame[:, :width])
        cv2.imwrite(str(args.out / "right" / f"frame_{index:03d}.png"), frame[:, width:])
    stereo = {"right": right, "R": (u @ vt).tolist(), "T": translation.tolist()}
    camera = left | {"encoding": "srgb", "stereo": stereo}
    (args.out / "camera.json").write_text(json.dumps(camera, indent=2))
    print(f"wrote {len(frames)} stereo pairs, {width}x{height}, to {args.out}")


if __name__ == "__main__":
    main()
