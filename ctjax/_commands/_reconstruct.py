"""`ctjax reconstruct`: depth, normals and poses from the images (structure from motion)."""

import argparse
import sys
from pathlib import Path

from ._args import output_file, output_folder


def add_reconstruct_parser(commands) -> None:
    recon = commands.add_parser(
        "reconstruct", help="depth, normals and poses from the images (structure-from-motion)"
    )
    recon.add_argument("capture", type=Path, help="capture folder (images and camera.json)")
    recon.add_argument("--out", type=output_folder, help="output capture folder (default: CAPTURE)")
    scale = recon.add_mutually_exclusive_group()
    scale.add_argument(
        "--scale-mm",
        type=float,
        metavar="X",
        help="median depth of the first registered frame, mm (else depth is up to scale)",
    )
    scale.add_argument(
        "--volume-mm3",
        type=float,
        metavar="V",
        help="bounding-box volume of the reconstructed points, mm^3 (the paper's known size)",
    )
    recon.add_argument("--force", action="store_true", help="overwrite depth, normals, poses")
    recon.add_argument(
        "--no-photometric",
        action="store_true",
        help="keep the surfaces fitted to the SfM points alone (not refined by the texture)",
    )
    recon.add_argument(
        "--texture-smoothing",
        type=float,
        metavar="X",
        help="the texture refinement's thin-plate penalty, relative to the data (default 5; "
        "2 gave better normals on synthetic captures and worse on a real sinus video: docs, "
        "reconstruct)",
    )
    recon.add_argument(
        "--shading",
        nargs="?",
        const="camera",
        choices=("camera", "near"),  # ctjax.sfm._reconstruct.SHADING_LIGHTS (it loads JAX)
        metavar="LIGHT",
        help="then refine the shape by every frame's shading, one world surface fitted with "
        "the BRDF under the light at the camera (camera, the default) or jointly with a near "
        "light's position (near: inverse-square falloff; for a capture whose light is off "
        "the lens); about 15-30 s at 640x512 x 8",
    )
    recon.add_argument(
        "--stereo",
        choices=("scale", "surface", "none", "pairs"),
        default="scale",
        help="on a stereo capture (right/NAME.png, camera.json's stereo): the pairs' depth "
        "gives the scale in mm (scale), and also dense points for the surfaces (surface; "
        "noisier normals on the synthetic captures), or is not used (none); pairs: no SfM, "
        "each frame's depth from its own pair and poses by PnP (a scope held still)",
    )
    recon.add_argument(
        "--focal",
        choices=("fixed", "refine"),
        default="fixed",
        help="the camera's focal length: 'fixed' (default) or 'refine'd by bundle adjustment "
        "from two starts and kept where they agree (a video without calibration, read with "
        "a guessed camera); the refined one is written into the output's camera.json",
    )
    recon.add_argument(
        "--knot-px",
        type=float,
        metavar="PX",
        help="the dense surfaces' knot spacing in pixels (default: a twentieth of the image's "
        "larger side): the finest relief their normals resolve; finer is noisier",
    )
    recon.add_argument("--verbose", action="store_true", help="show COLMAP's own log on stderr")
    recon.add_argument("--json", type=output_file, help="write the report to this JSON file")
    recon.set_defaults(run=run_reconstruct)


def run_reconstruct(args: argparse.Namespace) -> int:
    from ..io._atomic import atomic_write_json
    from ..sfm import reconstruct

    report = reconstruct(
        args.capture,
        args.out,
        scale_mm=args.scale_mm,
        volume_mm3=args.volume_mm3,
        force=args.force,
        photometric=not args.no_photometric,
        texture_smoothing=args.texture_smoothing,
        shading=args.shading,
        stereo=args.stereo,
        focal=args.focal,
        knot_spacing_px=args.knot_px,
        progress=lambda m: print(f"[ctjax reconstruct] {m}", flush=True),
        verbose=args.verbose,
    )
    for note in report["notes"]:
        print(f"ctjax reconstruct: note: {note}", file=sys.stderr)
    if args.json is not None:
        atomic_write_json(args.json, report)
    scale = report["scale"]
    unit = "mm" if scale["metric"] else "up to scale (unit: median depth of the first frame)"
    print(
        f"registered {len(report['registered'])}/{report['frames']} frames, "
        f"{report['points']} points, mean reprojection error "
        f"{report['mean_reprojection_error_px']:.2f} px, coverage {report['coverage']:.1%}; "
        f"depth {unit}; wrote {report['out']}"
    )
    focal = report["focal"]
    if focal["status"] == "refined":
        given, refined = focal["given_fx_fy_px"], focal["fx_fy_px"]
        print(
            f"focal length refined: fx, fy {given[0]:.1f}, {given[1]:.1f} -> {refined[0]:.1f}, "
            f"{refined[1]:.1f} px (two starts within {focal['relative_difference']:.1%})"
        )
    elif focal["status"] == "undetermined":
        print(f"ctjax reconstruct: warning: {focal['note']}", file=sys.stderr)
    shading = report["surface"].get("shading")
    if shading and shading["refined"]:
        print(
            f"shape refined by the shading: {shading['points']} points, sigma "
            f"{shading['sigma_before']:.4f} -> {shading['sigma_after']:.4f}, normals turned by "
            f"{shading['median_normal_change_deg']:.2f} degrees (median)"
        )
        if "light" in shading:
            unit = "mm" if scale["metric"] else "median depths"
            position = ", ".join(f"{x:.2f}" for x in shading["light"]["position_mm"])
            print(f"near light fitted with the shape: position ({position}) {unit}")
    elif shading:
        print(
            f"ctjax reconstruct: warning: no shading refinement: {shading['reason']}",
            file=sys.stderr,
        )
    for warning in report["warnings"]:
        print(f"ctjax reconstruct: warning: {warning}", file=sys.stderr)
    return 0
