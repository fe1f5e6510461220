"""Which frames do the others predict? Each frame's views of the tracked points, each predicted
from the point's albedo in its other views.

    python benchmarks/frame_consistency.py CAPTURE [--calib N] [--factor 1.5] [--near]

The held-out protocol of `ctjax evaluate` and `ctjax fit` (`ctjax.heldout.HeldOutTracks`):
the paper's model with the albedo map fitted on the calibration frames (the first 60%),
then every view of a tracked point predicted with the model fixed and the point's albedo
fitted to its other views (`heldout_map_residuals`), on the calibration frames (every view)
and on the held-out ones (the judged views). Printed per frame: that RMSE (8-bit levels)
and the views it counts; the calibration frames whose RMSE exceeds `--factor` times their
median are named. No lobe explains a frame that its neighbours do not predict under any
model: the tissue moved, the pose or the shape is off there, or the frame is blurred.
Beside it each frame's brightness against what the others predict
(`HeldOutTracks.frame_brightness`, measured over predicted) and the frames off by more than
`BRIGHTNESS_OFF_LOG` (10%), as `ctjax evaluate` prints them; `--near`: under
`calibrate_near_light`'s model (its falloff chosen; minutes) as evaluate's are, instead of
the paper's light at the lens.

Measured (2026-11-28): all 35 frames of the shared sinus at 640 px (`ctjax reconstruct`:
35 of 35, 880 points): the calibration frames' RMSE runs from 5.8 to 33.8 levels (median
14.4; frames 0, 1, 7, 9, 10 and 11 above 1.5x it), the held-out frames' 3.4-9.0 (5.08 in
all). Without the first 12 frames (frames 12-34 as their own capture): `ctjax fit` sigma
0.167 +- 0.016, F_tilde [0.0037, 0.0017, 0.0011], halves 0.159 / 0.206 (`unstable`),
where all 35 gave `no_lobe` (halves 0.028 / 0.016); `ctjax evaluate --no-sfs` 5.04 ->
4.28 levels (0.849x), all of it the near light's (the lobe 0.00). Without only the six
named frames the fit stays `no_lobe` (sigma 0.009). The cholecystectomy's 12
frames (session 34's reconstruction): 16.2-23.3 levels in the calibration frames (median
17.8), none above 1.5x; 17.4-26.8 in the held-out ones: there every frame is predicted as
badly as the others.
"""

import argparse
from pathlib import Path

import numpy as np
from _results import emit

from ctjax.calibration import calibrate_near_light
from ctjax.fitting import fit_model_map, paper_model
from ctjax.fitting._map_least_squares import heldout_map_residuals
from ctjax.heldout import BRIGHTNESS_OFF_LOG, HeldOutTracks
from ctjax.io import load_capture


def per_frame(model, samples, judged=None) -> dict[int, tuple[float, int]]:
    """frame -> (RMSE in 8-bit levels, views counted) of `samples`' judged views."""
    residual, weight = heldout_map_residuals(model, samples, judged)
    frame = np.asarray(samples.site.frame)
    squared = (residual**2).sum(0) * weight
    out = {}
    for f in np.unique(frame[weight > 0]):
        here = (frame == f) & (weight > 0)
        out[int(f)] = (
            float(np.sqrt(squared[here].sum() / (weight[here].sum() * residual.shape[0]))),
            int(here.sum()),
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("capture", type=Path, help="a capture with depth and poses")
    parser.add_argument("--calib", type=int, help="calibration frames (default 60%%)")
    parser.add_argument(
        "--factor", type=float, default=1.5, help="name the frames above this x the median"
    )
    parser.add_argument(
        "--near", action="store_true", help="the near light's model (calibrate_near_light)"
    )
    args = parser.parse_args()
    capture = load_capture(args.capture)
    split = HeldOutTracks.split(capture, args.calib)
    if args.near:
        model = calibrate_near_light(capture, calibration=len(split.calibration)).model
    else:
        model = fit_model_map(paper_model(sigma=0.3), split.train, standard_errors=False).model
    brightness = split.frame_brightness(model)
    names = [frame.name for frame in capture.frames]
    calibration = per_frame(model, split.train)
    heldout = per_frame(model, split.test, split.judged)
    median = float(np.median([rmse for rmse, _ in calibration.values()]))
    for part, figures in (("calibration", calibration), ("heldout", heldout)):
        for f, (rmse, views) in figures.items():
            emit(
                {
                    "part": part,
                    "frame": names[f],
                    "index": f,
                    "rmse": rmse,
                    "views": views,
                    "brightness": brightness[f],
                }
            )
    outliers = [names[f] for f, (rmse, _) in calibration.items() if rmse > args.factor * median]
    emit(
        {
            "capture": str(args.capture),
            "calibration_median_rmse": median,
            "factor": args.factor,
            "calibration_frames_above": outliers,
            "model": "near light" if args.near else "the paper's, light at the lens",
            "log_brightness_sd": float(np.nanstd(np.log(list(brightness.values())))),
            "brightness_off": [
                names[f] for f, g in brightness.items() if abs(np.log(g)) > BRIGHTNESS_OFF_LOG
            ],
        }
    )


if __name__ == "__main__":
    main()
