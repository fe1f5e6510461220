"""Shape from SfM against synthetic ground truth: registered frames, points, reprojection error,
coverage and the angular error of the normals inside the points' convex hull.

    .venv/bin/python benchmarks/sfm.py CAPTURE [CAPTURE ...]

Each CAPTURE is a synthetic capture (`ctjax synth`) with depth/ and normals/ (the truth).
"""

import sys
import time

import numpy as np
from _results import emit

from ctjax.io import load_capture
from ctjax.sfm import reconstruct_capture


def normal_errors(capture, result) -> np.ndarray:
    """Angles (degrees) between reconstructed and true normals, covered pixels of all frames."""
    errors = []
    for frame in capture.frames:
        view = result.views.get(frame.name)
        if view is None:
            continue
        _, normals = view.depth_and_normals(capture.camera)
        ok = view.hull & np.all(np.isfinite(frame.normals), -1) & np.all(np.isfinite(normals), -1)
        cosine = np.clip(np.sum(normals[ok] * frame.normals[ok], -1), -1, 1)
        errors.append(np.degrees(np.arccos(cosine)))
    return np.concatenate(errors)


def main(paths):
    for path in paths:
        capture = load_capture(path)
        started = time.perf_counter()
        result = reconstruct_capture(capture)
        seconds = time.perf_counter() - started
        errors = normal_errors(capture, result)
        report = result.report
        row = {
            "capture": path,
            "size": f"{capture.camera.width}x{capture.camera.height}",
            "registered": f"{len(report['registered'])}/{report['frames']}",
            "points": report["points"],
            "reprojection_px": round(report["mean_reprojection_error_px"], 3),
            "coverage": round(report["coverage"], 3),
            "normal_median_deg": round(float(np.median(errors)), 2),
            "normal_p90_deg": round(float(np.percentile(errors, 90)), 2),
            "seconds": round(seconds, 1),
        }
        emit(row)


if __name__ == "__main__":
    if not sys.argv[1:] or {"-h", "--help"} & set(sys.argv[1:]):
        print(__doc__)
        sys.exit(0 if sys.argv[1:] else 2)
    main(sys.argv[1:])
