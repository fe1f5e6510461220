"""Do the highlights sit where the reconstructed normals say N = H? One figure per highlight.

    python benchmarks/highlight_normals.py RECONSTRUCTED_CAPTURE [...]

For every connected component of S (`ctjax.specular.capture_sets`, the fit's own sets) in
every frame: the angle between the surface normal and H at its peak (its brightest pixel, or
the middle of its clipped core, as `ctjax.specular.highlight_peaks` takes it; the light at
the lens: H = V), and the direction, in the image plane, in which N leans away from H. Under
the right normals a highlight's peak is where N = H (0 degrees) whatever the surface's
roughness; the same figures over all pixels of the field say how far N = H is from a pixel
taken at random. The lean's mean resultant length says whether the highlights' normals miss
H in one direction (1: a bias of the shape, or a light off the lens) or in any (0: relief
finer than the shape, noise); its mean cosine with the outward radial direction whether the
bias points away from the image centre (+1) or towards it (-1).

Measured (2026-11-28, 12 frames at 640 px, `benchmarks/real_video.py`'s preparation, then
`ctjax reconstruct`): the shared sinus (its calibrated camera, 741 SfM points): 20
highlights, median 24.7 deg (the largest quarter 18.6), all pixels 57.1 deg; the lean one
way (resultant 0.65), towards the centre (cosine -0.81). The cholecystectomy video (`ctjax
import --camera guess`, `reconstruct --focal refine`: 373 px): 706 highlights, median 34.0
deg (the largest quarter 34.9), all pixels 39.3 deg; the lean one way (0.81), as every
pixel's (0.73): its highlights hardly follow the reconstructed normals at all.
The stereo SurgT da Vinci clip (`benchmarks/surgt_capture.py`, 10 frames at 640 px,
`reconstruct --stereo pairs`): 1315 highlights, median 26.8 deg (24.2), all pixels 52.4
deg; no one way (0.33, all pixels 0.45; outward cosine 0.02).

`--rotated OUT` writes a copy of one capture with its normals turned by the rotation that
`ctjax.specular.highlight_alignment` fits to the first frames' peaks (`ctjax fit` reports
the same block): on the cholecystectomy a 29.7-degree tilt, the later frames' peaks from
36.2 to 13.6 degrees; `ctjax fit` on the copy then finds less of a lobe, not more
(docs/real-video.md, "One rotation of the normals").
"""

import argparse
import shutil
from pathlib import Path

import cv2
import numpy as np
from _results import emit

from ctjax.io import load_capture
from ctjax.specular import capture_sets, highlight_alignment
from ctjax.specular._highlight_alignment import _peaks

# Highlights by distance from the principal point (image widths): [count, median angle].
RINGS = ((0, 0.15), (0.15, 0.3), (0.3, 1))


def _unit(a):
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _lean(normal, half):
    """The angle between N and H (degrees) and the unit direction, in the image plane, in
    which N leans away from H."""
    cos = np.clip(np.sum(normal * half, -1), -1, 1)
    away = normal - cos[..., None] * half
    return np.degrees(np.arccos(cos)), _unit(away[..., :2])


def highlight_normals(root: Path, samples: int = 5000, seed: int = 0) -> dict:
    capture = load_capture(root)
    camera = capture.camera
    fx, fy, cx, cy = (float(x) for x in (camera.fx, camera.fy, camera.cx, camera.cy))
    rng = np.random.default_rng(seed)
    peaks, leans, outward, sizes, everywhere, every_lean = [], [], [], [], [], []
    radius = []  # each highlight's distance from the principal point, in image widths
    for frame, sets in zip(capture.frames, capture_sets(capture), strict=True):
        valid = frame.geometry_mask & np.all(np.isfinite(frame.normals), -1)
        ray = lambda x, y: np.stack([(x - cx) / fx, (y - cy) / fy, np.ones_like(x)], -1)  # noqa: E731
        count, labels = cv2.connectedComponents((sets.specular & valid).astype(np.uint8), None, 8)
        peak_ys, peak_xs = _peaks(labels, count, frame.image.mean(-1))
        piece_sizes = np.bincount(labels.reshape(-1), minlength=count)
        for k in range(1, count):
            y, x = peak_ys[k - 1], peak_xs[k - 1]
            angle, lean = _lean(_unit(frame.normals[y, x].astype(np.float64)), -_unit(ray(x, y)))
            peaks.append(angle)
            leans.append(lean)
            outward.append(float(lean @ _unit(np.array([x - cx, y - cy]))))
            sizes.append(int(piece_sizes[k]))
            radius.append(float(np.hypot(x - cx, y - cy)) / camera.width)
        ys, xs = np.nonzero(valid)
        pick = rng.choice(len(xs), min(samples, len(xs)), replace=False)
        ys, xs = ys[pick], xs[pick]
        angle, lean = _lean(
            _unit(frame.normals[ys, xs].astype(np.float64)),
            -_unit(ray(xs.astype(np.float64), ys.astype(np.float64))),
        )
        everywhere.append(angle)
        every_lean.append(lean)
    if not peaks:
        return {"capture": str(root), "highlights": 0}
    peaks, sizes, everywhere = np.array(peaks), np.array(sizes), np.concatenate(everywhere)
    largest = sizes >= np.percentile(sizes, 75)
    radius = np.array(radius)
    rings = {}
    for lo, hi in RINGS:
        inside = (radius >= lo) & (radius < hi)
        rings[f"{lo}-{hi}"] = [
            int(inside.sum()),
            float(np.median(peaks[inside])) if inside.any() else None,
        ]
    return {
        "capture": str(root),
        "frames": len(capture.frames),
        "highlights": len(peaks),
        "highlight_size_px_median": float(np.median(sizes)),
        "angle_deg_median": float(np.median(peaks)),
        "angle_deg_p25_p75": [float(np.percentile(peaks, 25)), float(np.percentile(peaks, 75))],
        "angle_deg_median_largest_quarter": float(np.median(peaks[largest])),
        "all_pixels_angle_deg_median": float(np.median(everywhere)),
        "lean_resultant": float(np.linalg.norm(np.mean(leans, 0))),
        "lean_outward_cosine_mean": float(np.mean(outward)),
        "all_pixels_lean_resultant": float(np.linalg.norm(np.concatenate(every_lean).mean(0))),
        "angle_deg_median_by_radius": rings,
    }


def write_rotated(root: Path, out: Path) -> dict:
    """A copy of the capture at `root` in `out` with every frame's normals turned by
    `ctjax.specular.highlight_alignment`'s rotation (world coordinates, by the poses), its
    shape otherwise the same: to fit the lobe about normals that place the highlights."""
    capture = load_capture(root)
    alignment = highlight_alignment(capture)
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(root, out)
    for frame in capture.frames:
        turn = np.asarray(frame.pose, float)[:3, :3]
        normals = np.load(root / "normals" / f"{frame.name}.npy").astype(np.float64)
        turned = normals @ (turn.T @ alignment.rotation @ turn).T
        np.save(out / "normals" / f"{frame.name}.npy", turned.astype(np.float32))
    return {"capture": str(root), "rotated": str(out), **alignment.to_json()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("captures", nargs="+", type=Path)
    parser.add_argument(
        "--rotated",
        type=Path,
        help="(one capture) also write a copy of it here, its normals turned by "
        "highlight_alignment's rotation",
    )
    args = parser.parse_args()
    if args.rotated is not None:
        if len(args.captures) != 1:
            parser.error("--rotated takes one capture")
        emit(write_rotated(args.captures[0], args.rotated))
    for root in args.captures:
        row = highlight_normals(root)
        emit(row)
        if row["highlights"]:
            print(
                f"{root}: {row['highlights']} highlights in {row['frames']} frames; angle N-H at"
                f" their peaks median {row['angle_deg_median']:.1f} deg (largest quarter"
                f" {row['angle_deg_median_largest_quarter']:.1f}), all pixels"
                f" {row['all_pixels_angle_deg_median']:.1f}; lean resultant"
                f" {row['lean_resultant']:.2f} (all pixels {row['all_pixels_lean_resultant']:.2f}),"
                f" outward cosine {row['lean_outward_cosine_mean']:.2f}; by distance from the"
                " centre (image widths): "
                + ", ".join(
                    f"{ring} {count} at {median:.1f} deg"
                    for ring, (count, median) in row["angle_deg_median_by_radius"].items()
                    if count
                )
            )


if __name__ == "__main__":
    main()
