"""Do the test frames' highlights shine where the calibration frames' did? Of the test
frames' views in S, the share whose surface point was in (or near) S in a calibration frame.

    python benchmarks/sparkle_recurrence.py CAPTURE [--calib N]

`ctjax evaluate`'s split (the first 60% of the frames calibrate, `ctjax.heldout.split_frames`)
and its surface points (`Observations.tracks`, every frame): a tracked point's view is "in S"
where its pixel lies in the frame's specular set (`Observations.specular_distance` under 1
px). A model that remembers where each point shone (the lobe about every point's own facet,
`evaluate --facets`) can predict a test frame's highlight only at a point that shone in a
calibration frame: this prints the share of the test frames' views in S at such points (within
1 and 3 px of S there), whether the point was tracked in a calibration frame at all, and how
often a calibration frame's view in S recurs in another calibration frame.

Measured (2026-12-05, 8e0baf3; 640 px, reconstructions from `benchmarks/real_video.py` and
`benchmarks/scared_capture.py`): the second sinus video's turbinate (A, 24 frames, 15
calibrating; the facet lobe 0.966x Lambert's) 56.4% within 1 px, 72.0% within 3 px (tracked
in a calibration frame: 93.4%; calibration views in S recurring: 88.7%); SCARED 61-84 (24
frames; the facet lobe 0.73x) 69.1% / 85.7% (94.0%; 94.3%); the shared cholecystectomy (12
frames, 8 calibrating; the facet lobe 0.98x) 70.6% / 86.7% (99.9%; 79.9%); A at every
2nd frame (the facet lobe 1.000x) 80.6% / 88.9% (90.7%; 95.6%).
docs/real-video.md, "Do the test frames' highlights shine where the calibration frames'
did?".
"""

import argparse

import numpy as np
from _results import emit


def distance_to_s(observations, samples) -> np.ndarray:
    """Every observed view's distance (px) to its frame's S (`TrackSamples`' (M, P)); inf
    where unobserved."""
    seen = np.asarray(samples.weight) > 0
    frame = np.asarray(samples.site.frame)
    u, v = (np.asarray(a) for a in samples.site.pixel)
    distance = np.full(frame.shape, np.inf)
    for f in np.unique(frame[seen]):
        to_s = observations.specular_distance(int(f))
        here = seen & (frame == f)
        rows = np.clip(np.rint(v[here]).astype(int), 0, to_s.shape[0] - 1)
        cols = np.clip(np.rint(u[here]).astype(int), 0, to_s.shape[1] - 1)
        distance[here] = to_s[rows, cols]
    return distance


def recurrence(root, calibration: int | None = None) -> dict:
    from ctjax.fitting import TrackSamples
    from ctjax.heldout import split_frames
    from ctjax.io import load_capture
    from ctjax.observations import Observations

    observations = Observations.of(load_capture(root))
    calib, _ = split_frames(len(observations), calibration, source=observations.root)
    samples = TrackSamples.of(observations.tracks())
    seen = np.asarray(samples.weight) > 0  # (views, points)
    frame = np.asarray(samples.site.frame)
    distance = distance_to_s(observations, samples)
    in_calibration = seen & np.isin(frame, calib)
    in_s = seen & (distance < 1)
    test_in_s = in_s & ~in_calibration
    points = np.nonzero(test_in_s)[1]
    out = {
        "capture": str(root),
        "frames": len(observations),
        "calibration_frames": len(calib),
        "test_views_in_s": int(test_in_s.sum()),
        "tracked_in_calibration": float(np.mean(np.any(in_calibration, 0)[points])),
    }
    for radius in (1, 3):
        shone = np.any(in_calibration & (distance < radius), axis=0)
        out[f"shone_within_{radius}px"] = float(np.mean(shone[points]))
    # A calibration view in S whose point is in S in another calibration frame.
    calibration_in_s = in_s & in_calibration
    per_point = calibration_in_s.sum(0)
    counted = per_point[np.nonzero(calibration_in_s)[1]]
    out["calibration_recurring"] = float(np.mean(counted > 1)) if counted.size else float("nan")
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", help="a reconstructed capture (depth, normals, poses)")
    parser.add_argument("--calib", type=int, default=None, help="calibration frames (60%% of them)")
    args = parser.parse_args()
    found = recurrence(args.capture, args.calib)
    print(
        f"{found['capture']}: {found['frames']} frames, {found['calibration_frames']} "
        f"calibrating; {found['test_views_in_s']} test views in S, their point shone in a "
        f"calibration frame within 1 px of S {found['shone_within_1px']:.1%}, within 3 px "
        f"{found['shone_within_3px']:.1%} (tracked there at all "
        f"{found['tracked_in_calibration']:.1%}); calibration views in S that recur in "
        f"another calibration frame {found['calibration_recurring']:.1%}"
    )
    emit({"benchmark": "sparkle_recurrence", **found})


if __name__ == "__main__":
    main()
