"""`ctjax import`: a capture from a video, its distinct and sharp frames."""

import argparse
import sys
from pathlib import Path

from ._args import output_file, output_folder

# `ctjax import` warns above this many kept frames.
MANY_FRAMES = 200


def add_import_parser(commands) -> None:
    from ..io._video import ImportOptions

    default = ImportOptions()
    video = commands.add_parser(
        "import",
        help="a capture from a video: its distinct, sharp frames",
        description="Keeps the video's distinct frames (near-duplicates of a still camera "
        "dropped, the sharpest of each run kept) and drops motion-blurred ones; writes "
        "OUT/images/frame_NNNNNN.png (the frame number: names sort in time) and "
        "OUT/camera.json.",
    )
    video.add_argument(
        "video",
        type=Path,
        help="any video file OpenCV reads (MP4, AVI, MKV...), or a folder of images (its "
        "frames in name order; --start and --end then count files)",
    )
    video.add_argument(
        "--camera",
        type=Path,
        required=True,
        help="the endoscope's camera.json, an OpenCV calibration file (.yaml, .yml or .xml "
        "with M1, D1 and, for a stereo scope, M2, D2, R and T in mm: SCARED's "
        "endoscope_calibration.yaml), a da Vinci's StereoCalibration.ini (StereoMIS's), or "
        "'guess' for a video without a calibration (fx = fy "
        "= 0.8 width, the principal point at the centre; then `ctjax reconstruct --focal "
        "refine`)",
    )
    video.add_argument(
        "--out", type=output_folder, required=True, help="the capture folder to write"
    )
    video.add_argument(
        "--every", type=int, default=default.every, help="consider every N-th frame (default 1)"
    )
    video.add_argument("--start", type=float, default=0.0, help="from this time, s (default 0)")
    video.add_argument("--end", type=float, help="up to this time, s (default: the end)")
    video.add_argument(
        "--max-frames", type=int, help="keep at most this many, evenly in time (default: all)"
    )
    video.add_argument(
        "--distinct",
        type=float,
        default=default.distinct,
        help="a new view differs from the last by this much, relative to the mean "
        f"brightness (default {default.distinct})",
    )
    video.add_argument(
        "--width",
        type=int,
        help="write the frames this many pixels wide (area-averaged; camera.json scaled to "
        "match; default: the video's size)",
    )
    video.add_argument(
        "--right",
        type=Path,
        help="a stereo laparoscope's right video (or folder of images), frame for frame with "
        "VIDEO (camera.json needs its stereo block); writes OUT/right/frame_NNNNNN.png",
    )
    video.add_argument(
        "--side-by-side",
        action="store_true",
        help="a stereo video with the left camera's image in each frame's left half and the "
        "right camera's in its right half (camera.json needs its stereo block)",
    )
    video.add_argument(
        "--top-bottom",
        action="store_true",
        help="a stereo video with the left camera's image in each frame's top half and the "
        "right camera's in its bottom half (SCARED's rgb.mp4; camera.json needs its stereo "
        "block)",
    )
    video.add_argument(
        "--excluded",
        type=Path,
        help="masks of what is not tissue (surgical instruments: white, above half scale), a "
        "video or folder of images frame for frame with VIDEO and laid out as it (writes "
        "OUT/excluded/frame_NNNNNN.png), or one image for every frame (an overlay: writes "
        "OUT/excluded.png); pixels no command uses",
    )
    video.add_argument(
        "--right-excluded",
        type=Path,
        help="the same for the right video (--right); writes OUT/excluded/right/",
    )
    video.add_argument(
        "--force",
        action="store_true",
        help="replace OUT/images (and the depth, normals and poses reconstructed from them)",
    )
    video.add_argument("--json", type=output_file, help="write the report to this JSON file")
    video.set_defaults(run=run_import)


def run_import(args: argparse.Namespace) -> int:
    import json
    import tempfile

    from .._errors import ParameterError
    from ..io._atomic import atomic_write_json
    from ..io._capture import BASELINE_MM, unlikely_baseline
    from ..io._davinci_calibration import is_davinci_calibration
    from ..io._opencv_calibration import is_opencv_calibration
    from ..io._video import ImportOptions, guessed_camera, import_video

    # The options checked first: a bad one is the only line, before any note.
    options = ImportOptions(
        every=args.every,
        start=args.start,
        end=args.end,
        max_frames=args.max_frames,
        distinct=args.distinct,
        width=args.width,
        side_by_side=args.side_by_side,
        top_bottom=args.top_bottom,
    )
    if str(args.camera) == "guess":
        if options.stacked or args.right is not None:
            raise ParameterError(
                "a stereo import (--right, --side-by-side, --top-bottom) needs the stereo "
                "calibration: "
                'camera.json\'s "stereo" block (the right camera, R and T in mm); --camera '
                "guess has none"
            )
        guess = guessed_camera(args.video, args.side_by_side, args.top_bottom)
        folder = tempfile.TemporaryDirectory(prefix="ctjax-camera-")
        args.camera = Path(folder.name) / "camera.json"
        args.camera.write_text(json.dumps(guess))
        # In the frames written: --width scales the guess with them.
        fx = guess["fx"] * (1 if args.width is None else args.width / guess["width"])
        print(
            f"ctjax import: note: no calibration: a guessed camera, fx = fy = {fx:.1f} px "
            "(0.8 width), the principal point at the centre; `ctjax reconstruct OUT --out DIR "
            "--focal refine` refines the focal length from the frames",
            file=sys.stderr,
        )

    report = import_video(
        args.video,
        args.camera,
        args.out,
        options,
        right=args.right,
        excluded=args.excluded,
        right_excluded=args.right_excluded,
        force=args.force,
        progress=lambda m: print(f"[ctjax import] {m}", flush=True),
    )
    if args.json is not None:
        atomic_write_json(args.json, report)
    print(f"wrote {report['kept']} frames to {report['out']}")
    davinci = is_davinci_calibration(args.camera)
    if davinci or is_opencv_calibration(args.camera):
        print(
            f"ctjax import: note: the camera from {'a da Vinci' if davinci else 'OpenCV'}'s "
            f"calibration {args.camera}"
            + (
                f"; its T read in mm: a baseline of {report['baseline_mm']:.3g} mm"
                if "baseline_mm" in report
                else ""
            ),
            file=sys.stderr,
        )
    baseline = report.get("baseline_mm")
    if baseline is not None and not BASELINE_MM[0] <= baseline <= BASELINE_MM[1]:
        # What loading the capture notes, said where the unit came in.
        print(f"ctjax import: warning: {unlikely_baseline(args.out, baseline)}", file=sys.stderr)
    if report["kept"] < 3:
        print(
            f"ctjax import: warning: {report['kept']} distinct frame(s): structure from motion "
            "needs views from several positions (a lower --distinct keeps more)",
            file=sys.stderr,
        )
    elif report["kept"] > MANY_FRAMES:
        print(
            f"ctjax import: warning: {report['kept']} frames kept: structure from motion and "
            "the fits on that many take long; --max-frames or --every keeps fewer",
            file=sys.stderr,
        )
    return 0
