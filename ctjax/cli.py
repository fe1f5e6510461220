"""The `ctjax` command line: `ctjax synth`, `ctjax demo`.

Bad input is reported on one line naming the problem (and the file), exit status 2, no
traceback.
"""

import argparse
import sys
from pathlib import Path

from ._errors import CtjaxError
from ._units import in_length_unit, label


def _synth_options_from(args: argparse.Namespace):
    from .synth import SynthOptions, synth_effects

    effects = {}
    for name, effect in synth_effects().items():
        value = effect.synth_value(args)
        if value is not None:
            effects[name] = value
    return SynthOptions(
        width=args.width,
        height=args.height,
        frames=args.frames,
        seed=args.seed,
        texture=not args.no_texture,
        texture_contrast=args.texture_contrast,
        noise_levels=args.noise,
        bits=args.bits,
        rho_tilde=tuple(args.rho) if args.rho else SynthOptions.rho_tilde,
        F_tilde=tuple(args.F) if args.F else SynthOptions.F_tilde,
        sigma=args.sigma,
        effects=effects,
        stereo_mm=getattr(args, "stereo", None),
    )


def _add_synth_arguments(
    parser: argparse.ArgumentParser, *, frames: int, texture: bool, texture_contrast: float = 1.0
) -> None:
    from .synth import SynthOptions, synth_effects

    size = parser.add_argument_group("capture")
    size.add_argument("--frames", type=int, default=frames, help="number of frames")
    size.add_argument("--seed", type=int, default=0, help="random seed (organ, path, noise)")
    size.add_argument("--width", type=int, default=SynthOptions.width)
    size.add_argument("--height", type=int, default=SynthOptions.height)
    size.add_argument(
        "--stereo",
        type=float,
        metavar="BASELINE_MM",
        help="a stereo laparoscope: right images from a camera this far right (mm)",
    )
    if texture:
        size.add_argument("--no-texture", action="store_true", help="uniform albedo")
    else:
        size.set_defaults(no_texture=True)
    size.add_argument(
        "--texture-contrast",
        type=float,
        default=texture_contrast,
        help="scale of the albedo texture's contrast, 0-1 (default %(default)s)",
    )
    size.add_argument("--noise", type=float, default=1.0, help="Gaussian noise, 8-bit levels")
    size.add_argument("--bits", type=int, default=8, choices=(8, 16), help="PNG bit depth")
    model = parser.add_argument_group("reflectance (linear units, 1.0 = 8-bit level 255)")
    model.add_argument("--rho", type=float, nargs=3, metavar=("R", "G", "B"), help="rho_tilde")
    model.add_argument("--F", type=float, nargs=3, metavar=("R", "G", "B"), help="F_tilde")
    model.add_argument("--sigma", type=float, default=SynthOptions.sigma, help="roughness")
    effects = parser.add_argument_group("effects beyond the paper's model (all off by default)")
    # Each effect declares its own options, beside its physics (its candidate).
    for effect in synth_effects().values():
        effect.add_synth_arguments(effects)


def _cmd_synth(args: argparse.Namespace) -> int:
    from .synth import synthesize

    out = synthesize(args.out, _synth_options_from(args))
    print(f"wrote synthetic capture to {out}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    summary = run_demo(Path(args.out), _synth_options_from(args), falloff=args.falloff)
    evaluation = summary["evaluation"]
    print(f"report: {Path(args.out) / 'report.html'}")
    print(
        f"summary: {Path(args.out) / 'summary.json'} (test-frame RGB RMSE: Cook-Torrance "
        f"{evaluation['cook_torrance_rgb_rmse_test']:.2f}, Lambertian "
        f"{evaluation['lambertian_rgb_rmse_test']:.2f} levels)"
    )
    return 0


def _add_mask_arguments(parser: argparse.ArgumentParser) -> None:
    from .estimation._highlights import HLSThresholds, WhiterThanTissue
    from .estimation._specular_set import DEFAULT_MIN_SPECK_PX, DEFAULT_RING_PX

    whiter, hls = WhiterThanTissue(), HLSThresholds()
    group = parser.add_argument_group(
        "specular set S and ring S~",
        "S: 'whiter' (default) takes pixels bright and whiter than the tissue around them, "
        "or clipped; 'hls' is the paper's rule (HLS lightness and saturation thresholds)",
    )
    group.add_argument(
        "--highlights",
        choices=("whiter", "hls"),
        default="whiter",
        help="the rule that finds S (default: whiter)",
    )
    group.add_argument(
        "--whiteness",
        type=float,
        default=whiter.whiteness,
        help="whiter: fraction of the way from the local tissue's colour to white "
        f"(default {whiter.whiteness})",
    )
    group.add_argument(
        "--contrast",
        type=float,
        default=whiter.contrast,
        help="whiter: luminance at least this times the local tissue's "
        f"(default {whiter.contrast})",
    )
    group.add_argument(
        "--lightness",
        type=float,
        default=None,
        help=f"hls: HLS lightness at least this (default {hls.lightness})",
    )
    group.add_argument(
        "--saturation",
        type=float,
        default=None,
        help=f"hls: HLS saturation at most this (default {hls.saturation})",
    )
    group.add_argument(
        "--ring-px",
        type=float,
        default=DEFAULT_RING_PX,
        help="S~: non-specular pixels within this distance of S "
        f"(default and paper: {DEFAULT_RING_PX})",
    )
    group.add_argument(
        "--min-speck",
        type=int,
        default=DEFAULT_MIN_SPECK_PX,
        help="drop specular specks smaller than this many pixels, 0 keeps all "
        f"(default {DEFAULT_MIN_SPECK_PX})",
    )


def _mask_options(args: argparse.Namespace):
    from .estimation._capture_fit import MaskOptions
    from .estimation._highlights import HLSThresholds, WhiterThanTissue

    if args.highlights == "hls":
        hls = HLSThresholds()
        rule = HLSThresholds(
            hls.lightness if args.lightness is None else args.lightness,
            hls.saturation if args.saturation is None else args.saturation,
        )
    else:
        if args.lightness is not None or args.saturation is not None:
            raise CtjaxError(
                "--lightness and --saturation set the paper's rule: add --highlights hls"
            )
        rule = WhiterThanTissue(whiteness=args.whiteness, contrast=args.contrast)
    return MaskOptions(rule, args.ring_px, args.min_speck)


def _load_capture(args: argparse.Namespace):
    """`args.capture` loaded, with its notes (how its images were decoded) on stderr."""
    from .io import load_capture

    capture = load_capture(args.capture)
    for note in capture.notes:
        print(f"ctjax {args.command}: note: {note}", file=sys.stderr)
    return capture


def _cmd_masks(args: argparse.Namespace) -> int:
    import numpy as np

    from .estimation._capture_fit import capture_sets
    from .io._images import write_mask

    capture = _load_capture(args)
    sets = capture_sets(capture, _mask_options(args))
    for frame, s in zip(capture.frames, sets, strict=True):
        for kind in ("specular", "ring"):
            write_mask(args.out / kind / f"{frame.name}.png", getattr(s, kind))
        write_mask(args.out / "saturated" / f"{frame.name}.png", s.clipped)
        write_mask(args.out / "fov" / f"{frame.name}.png", frame.visible)
        outside = int((~frame.visible).sum())
        clipped = s.clipped.sum(axis=(0, 1))
        print(
            f"{frame.name}: {int(s.specular.sum())} specular, {int(s.ring.sum())} ring pixels; "
            "clipped outside S: "
            + ", ".join(f"{c} {n}" for c, n in zip("RGB", clipped, strict=True))
            + (f"; {outside} outside the field of view" if outside else "")
        )
    total = int(np.sum([s.ring.sum() for s in sets]))
    print(f"wrote masks of {len(sets)} frame(s) to {args.out} ({total} ring pixels in all)")
    return 0


def _cmd_reconstruct(args: argparse.Namespace) -> int:
    from .io._atomic import atomic_write_json
    from .sfm import reconstruct

    report = reconstruct(
        args.capture,
        args.out,
        scale_mm=args.scale_mm,
        volume_mm3=args.volume_mm3,
        force=args.force,
        photometric=not args.no_photometric,
        shading=args.shading,
        stereo=args.stereo,
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
    shading = report["surface"].get("shading")
    if shading and shading["refined"]:
        print(
            f"shape refined by the shading: {shading['points']} points, sigma "
            f"{shading['sigma_before']:.4f} -> {shading['sigma_after']:.4f}, normals turned by "
            f"{shading['median_normal_change_deg']:.2f} degrees (median)"
        )
    elif shading:
        print(
            f"ctjax reconstruct: warning: no shading refinement: {shading['reason']}",
            file=sys.stderr,
        )
    for warning in report["warnings"]:
        print(f"ctjax reconstruct: warning: {warning}", file=sys.stderr)
    return 0


def _cmd_fit(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from .estimation import PAPER, TWO_SCALES
    from .estimation._capture_fit import fit_capture
    from .io._atomic import atomic_write_json, atomic_write_npy

    capture = _load_capture(args)
    shape = None
    if not any(frame.has_geometry for frame in capture.frames):
        from .sfm import with_reconstructed_shape

        print(
            f"ctjax fit: {args.capture} has images only; reconstructing its shape by SfM "
            "first (in memory; `ctjax reconstruct` writes it to the capture)"
            + ("" if args.no_shading else ", then refining it by the shading"),
            file=sys.stderr,
        )
        capture, shape = with_reconstructed_shape(capture, shading=not args.no_shading)
        for warning in shape["warnings"]:
            print(f"ctjax fit: warning: {warning}", file=sys.stderr)
    family = {"paper": PAPER, "two-scales": TWO_SCALES}[args.model]
    if args.albedo_maps is not None and args.albedo == "uniform":
        raise CtjaxError("--albedo-maps needs the albedo map (--albedo map)")
    if args.max_tracks is not None and args.albedo == "uniform":
        raise CtjaxError("--max-tracks is for the albedo map (--albedo map)")
    estimate = fit_capture(
        capture, _mask_options(args), family, albedo=args.albedo, max_points=args.max_tracks
    )
    if args.albedo_maps is not None:
        if "albedo" not in estimate.details or estimate.details["albedo"] != "map":
            raise CtjaxError(
                f"{args.capture}: --albedo-maps needs the albedo map, which needs depth and "
                "poses in every frame (poses.json), or a capture with images only"
            )
        for key, albedo in estimate.arrays.items():
            if key.startswith("albedo/"):
                name = key.removeprefix("albedo/")
                atomic_write_npy(args.albedo_maps / f"{name}.npy", albedo.astype(np.float32))
    result = estimate.to_json()
    if shape is not None:
        result["shape"] = {"source": "ctjax reconstruct (structure-from-motion)", **shape}
    atomic_write_json(args.json, in_length_unit(result, capture.length_unit))
    keys = ("rho_tilde", "F_tilde", "sigma", "rgb_rmse", "albedo", "status")
    print(json.dumps({k: result[k] for k in result if k in keys}))
    samples = (
        f"{result['n_points']} tracked points"
        if result["albedo"] == "map"
        else f"{result['n_ring_pixels']} ring pixels"
    )
    print(
        f"Lambertian: rgb_rmse {result['lambertian']['rgb_rmse']:.2f} levels; {samples}; "
        f"wrote {args.json}" + (f" and {args.albedo_maps}/" if args.albedo_maps else "")
    )
    halves = result.get("halves", {})
    if halves:
        names = [n for n in ("sigma", "sigma_1", "sigma_2") if n in halves["even_frames"]]
        print(
            "stability: "
            + "; ".join(
                f"{n} {halves['even_frames'][n]:.4g} (even frames) / "
                f"{halves['odd_frames'][n]:.4g} (odd)"
                for n in names
            )
        )
    for warning in result["warnings"]:
        print(f"ctjax fit: warning: {warning}", file=sys.stderr)
    return 0


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from .diagnostics import diagnose, diagnose_loop, diagnosis_plots, plot_loop
    from .io._atomic import atomic_write_json

    capture = _load_capture(args)
    options = dict(
        calibration=args.calib,
        add=tuple(args.add),
        albedo=args.albedo,
        max_samples=args.max_samples,
        progress=lambda m: print(f"[ctjax diagnose] {m}", flush=True),
    )
    loop = None
    if args.loop:
        loop = diagnose_loop(capture, max_rounds=args.max_rounds, **options)
        diagnosis = loop.final
    else:
        diagnosis = diagnose(capture, **options)
    summary = diagnosis.to_json()
    if loop is not None:
        summary["loop"] = loop.to_json()
    atomic_write_json(args.json, in_length_unit(summary, capture.length_unit))
    if args.plots:
        for path in diagnosis_plots(capture, diagnosis, args.plots):
            print(f"wrote {path}")
        if loop is not None:
            print(f"wrote {plot_loop(loop, Path(args.plots) / 'loop.png')}")
    if loop is not None:
        for k, step in enumerate(loop.steps):
            print(
                f"step {k + 1} ({' + '.join(['paper', *loop.added[:k]])}): held-out RMSE "
                f"{step.base_rmse:.2f} levels, {step.base_rmse / step.noise_floor:.2f}x the "
                f"noise floor {step.noise_floor:.2f}; verdict {step.verdict} "
                f"({step.seconds:.0f} s)"
            )
        print(f"loop stopped: {loop.stopped}; {loop.seconds:.0f} s in all")
    print(
        f"verdict: {diagnosis.verdict} (base held-out RMSE {diagnosis.base_rmse:.2f} levels, "
        f"noise floor {diagnosis.noise_floor:.2f}); wrote {args.json} "
        f"in {diagnosis.seconds:.0f} s"
    )
    return 0


def _cmd_calibrate_light(args: argparse.Namespace) -> int:
    from .calibration import calibrate_near_light, named_falloff
    from .io._atomic import atomic_write_json

    if args.model == "field":
        return _calibrate_light_field(args)
    capture = _load_capture(args)
    falloff = named_falloff(args.falloff, capture)
    result = calibrate_near_light(
        capture,
        calibration=args.calib,
        falloff=falloff,
        albedo=args.albedo,
        progress=lambda m: print(f"[ctjax calibrate-light] {m}", flush=True),
    )
    summary = result.to_json()
    atomic_write_json(args.json, in_length_unit(summary, capture.length_unit))
    offset = ", ".join(f"{v:.2f}" for v in summary["offset_mm"])
    if "offset_stderr_mm" in summary and summary.get("offset_detected", True):
        errors = summary["offset_stderr_mm"]
        offset += " +- " + ", ".join("?" if v is None else f"{v:.2f}" for v in errors)
    print(
        f"light offset ({offset}) {label(capture.length_unit)}, "
        f"falloff {'+'.join(summary['falloff']) or 'none'}, "
        f"albedo {summary['albedo']}, status {summary['status']}; "
        f"RGB RMSE {result.calibration_rmse:.2f} (calibration), {result.heldout_rmse:.2f} "
        f"(held-out) levels, noise floor {result.noise_floor:.2f}; wrote {args.json}"
    )
    for warning in result.warnings:
        print(f"ctjax calibrate-light: warning: {warning}", file=sys.stderr)
    return 0


def _calibrate_light_field(args: argparse.Namespace) -> int:
    import io

    import numpy as np

    from .calibration import calibrate_light_field
    from .io._atomic import atomic_write_bytes, atomic_write_json

    capture = _load_capture(args)
    result = calibrate_light_field(
        capture,
        calibration=args.calib,
        solver=_field_solver(args.engine),
        albedo=args.albedo,
        progress=lambda m: print(f"[ctjax calibrate-light] {m}", flush=True),
    )
    summary = result.to_json()
    atomic_write_json(args.json, in_length_unit(summary, capture.length_unit))
    if args.npz is not None:
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **result.arrays)
        atomic_write_bytes(args.npz, buffer.getvalue())
    counts = summary["solver_status"]
    print(
        f"light field over {summary['solved_pixels']} pixels (converged {counts['converged']}, "
        f"max steps {counts['max_steps']}, failed {counts['failed']}), median "
        f"{summary['median_angle_from_view_deg']:.2f} deg from the view direction, "
        f"albedo {summary['albedo']}, status {summary['status']}; "
        f"RGB RMSE {result.calibration_rmse:.2f} (calibration), {result.heldout_rmse:.2f} "
        f"(held-out) levels, noise floor {result.noise_floor:.2f}; wrote {args.json}"
        + (f" and {args.npz}" if args.npz is not None else "")
    )
    for warning in result.warnings:
        print(f"ctjax calibrate-light: warning: {warning}", file=sys.stderr)
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from .evaluation import evaluate, evaluation_plots
    from .io._atomic import atomic_write_json

    capture = _load_capture(args)
    evaluation = evaluate(
        capture,
        calibration=args.calib,
        cook_torrance=_cook_torrance_estimator(args.light),
        albedo=args.albedo,
        per_pixel_sfs=args.per_pixel_sfs,
        sfs=not args.no_sfs,
        progress=lambda m: print(f"[ctjax evaluate] {m}", flush=True),
    )
    summary = evaluation.to_json()
    atomic_write_json(args.json, in_length_unit(summary, capture.length_unit))
    if args.plots:
        for path in evaluation_plots(capture, evaluation, args.plots).values():
            print(f"wrote {path}")
    print(
        "RGB RMSE (levels), calibration / test: Lambertian "
        f"{summary['lambertian_rgb_rmse_calibration']:.2f} / "
        f"{summary['lambertian_rgb_rmse_test']:.2f}, Cook-Torrance "
        f"{summary['cook_torrance_rgb_rmse_calibration']:.2f} / "
        f"{summary['cook_torrance_rgb_rmse_test']:.2f} (albedo {summary['albedo']})"
    )
    gain = summary["gain"]
    if "lobe_levels" in gain:
        same = summary["lambertian_same_light_rgb_rmse_test"]
        print(
            "Cook-Torrance's gain on the test frames: "
            f"{gain['total_levels']:.2f} levels = {gain['light_levels']:.2f} from its light "
            f"(Lambertian under the same light: {same:.2f}) + {gain['lobe_levels']:.2f} from "
            "the lobe"
        )
    fitted = summary["models"]["cook_torrance"]
    for flagged in fitted["undetermined"]:
        print(
            f"ctjax evaluate: warning: Cook-Torrance's fit is {fitted['status']}: "
            f"{flagged['reason']}",
            file=sys.stderr,
        )
    for note in summary["notes"]:
        print(f"ctjax evaluate: note: {note}", file=sys.stderr)
    if summary["lambertian_sfs_error_mm"] is not None:
        models = [("Lambertian", "lambertian"), ("Cook-Torrance", "cook_torrance")]
        if args.per_pixel_sfs:
            models.append(("the paper's per-pixel refinement", "cook_torrance_per_pixel"))
        unit = label(capture.length_unit)
        for what, where in (("mean", ""), ("mean near highlights", "_near_highlights")):
            errors = (summary[f"{key}_sfs_error{where}_mm"] for _, key in models)
            figures = ", ".join(
                f"{name} {float('nan') if e is None else e:.2f}"
                for (name, _), e in zip(models, errors, strict=True)
            )
            print(f"SfS 3D error ({what}, {unit}): {figures}")
    print(f"wrote {args.json}")
    return 0


# The command line's words for objects, in one place.


def _field_solver(engine: str):
    """`--engine`: the light field's per-pixel solver."""
    from .calibration import FIELD_SOLVER, ClosedFormLM

    return {"optimistix": FIELD_SOLVER, "closed-form": ClosedFormLM(iterations=10)}[engine]


def _cook_torrance_estimator(light: str):
    """`--light`: how `ctjax evaluate` fits Cook-Torrance and its light."""
    from .calibration import calibrate_light_field, calibrate_near_light
    from .evaluation import fit_colocated

    return {
        "near": calibrate_near_light,
        "colocated": fit_colocated,
        "field": calibrate_light_field,
    }[light]


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse with bad options reported on one line (`ctjax fit: error: ...`), status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="ctjax",
        description="Cook-Torrance reflectance and laparoscope light from images (JAX).",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _synth_command(commands)
    _import_command(commands)
    _masks_command(commands)
    _recon_command(commands)
    _fit_command(commands)
    _diag_command(commands)
    _light_command(commands)
    _evaluate_command(commands)
    _demo_command(commands)
    _batch_command(commands)
    for command in commands.choices.values():
        _show_defaults(command)
    return parser


def _show_defaults(parser: argparse.ArgumentParser) -> None:
    """Every option's help ends with its default, where it has one and does not say it."""
    for action in parser._actions:
        if action.help is None or action.help == argparse.SUPPRESS or "default" in action.help:
            continue
        if action.default in (None, False, [], argparse.SUPPRESS) or not action.option_strings:
            continue
        value = action.default
        if isinstance(value, list | tuple):
            value = " ".join(str(v) for v in value)
        action.help += f" (default: {value})"


def _synth_command(commands) -> None:
    synth = commands.add_parser("synth", help="generate a synthetic laparoscope capture")
    synth.add_argument("out", type=Path, help="output capture folder")
    _add_synth_arguments(synth, frames=5, texture=True)
    synth.set_defaults(run=_cmd_synth)


def _import_command(commands) -> None:
    from .io._video import ImportOptions

    default = ImportOptions()
    video = commands.add_parser(
        "import",
        help="a capture from a video: its distinct, sharp frames",
        description="Keeps the video's distinct frames (near-duplicates of a still camera "
        "dropped, the sharpest of each run kept) and drops motion-blurred ones; writes "
        "OUT/images/frame_NNNNNN.png (the frame number: names sort in time) and "
        "OUT/camera.json.",
    )
    video.add_argument("video", type=Path, help="any video file OpenCV reads (MP4, AVI, MKV...)")
    video.add_argument("--camera", type=Path, required=True, help="the endoscope's camera.json")
    video.add_argument("--out", type=Path, required=True, help="the capture folder to write")
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
        help="a stereo laparoscope's right video, frame for frame with VIDEO (camera.json "
        "needs its stereo block); writes OUT/right/frame_NNNNNN.png",
    )
    video.add_argument(
        "--side-by-side",
        action="store_true",
        help="a stereo video with the left camera's image in each frame's left half and the "
        "right camera's in its right half (camera.json needs its stereo block)",
    )
    video.add_argument(
        "--force",
        action="store_true",
        help="replace OUT/images (and the depth, normals and poses reconstructed from them)",
    )
    video.add_argument("--json", type=Path, help="write the report to this JSON file")
    video.set_defaults(run=_cmd_import)


# `ctjax import` warns above this many kept frames.
MANY_FRAMES = 200


def _cmd_import(args: argparse.Namespace) -> int:
    from .io._atomic import atomic_write_json
    from .io._video import ImportOptions, import_video

    options = ImportOptions(
        every=args.every,
        start=args.start,
        end=args.end,
        max_frames=args.max_frames,
        distinct=args.distinct,
        width=args.width,
        side_by_side=args.side_by_side,
    )
    report = import_video(
        args.video,
        args.camera,
        args.out,
        options,
        right=args.right,
        force=args.force,
        progress=lambda m: print(f"[ctjax import] {m}", flush=True),
    )
    if args.json is not None:
        atomic_write_json(args.json, report)
    print(f"wrote {report['kept']} frames to {report['out']}")
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


def _masks_command(commands) -> None:
    masks = commands.add_parser("masks", help="specular set S and ring S~ of every frame")
    masks.add_argument("capture", type=Path, help="capture folder")
    masks.add_argument("--out", type=Path, required=True, help="folder for the PNG masks")
    _add_mask_arguments(masks)
    masks.set_defaults(run=_cmd_masks)


def _recon_command(commands) -> None:
    recon = commands.add_parser(
        "reconstruct", help="depth, normals and poses from the images (structure-from-motion)"
    )
    recon.add_argument("capture", type=Path, help="capture folder (images and camera.json)")
    recon.add_argument("--out", type=Path, help="output capture folder (default: CAPTURE)")
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
        "--shading",
        action="store_true",
        help="then refine the shape by every frame's shading, one world surface fitted with "
        "the BRDF (assumes the light at the camera; about 15 s at 640x512 x 8)",
    )
    recon.add_argument(
        "--stereo",
        choices=("scale", "surface", "none"),
        default="scale",
        help="on a stereo capture (right/NAME.png, camera.json's stereo): the pairs' depth "
        "gives the scale in mm (scale), and also dense points for the surfaces (surface; "
        "noisier normals on the synthetic captures), or is not used (none)",
    )
    recon.add_argument("--verbose", action="store_true", help="show COLMAP's own log on stderr")
    recon.add_argument("--json", type=Path, help="write the report to this JSON file")
    recon.set_defaults(run=_cmd_reconstruct)


def _fit_command(commands) -> None:
    from .observations import DEFAULT_MAX_TRACKS

    fit = commands.add_parser("fit", help="estimate (rho_tilde, F_tilde, sigma) from a capture")
    fit.add_argument(
        "capture", type=Path, help="capture folder (without depth or normals: reconstructed first)"
    )
    fit.add_argument("--json", type=Path, required=True, help="output JSON file")
    fit.add_argument(
        "--model",
        choices=("paper", "two-scales"),
        default="paper",
        help="paper: one Beckmann lobe (eq. 2); two-scales: two (eq. 3)",
    )
    fit.add_argument(
        "--albedo",
        choices=("map", "uniform"),
        help="map: rho_tilde per surface point from all frames (default when every frame has "
        "depth and a pose, or the shape is reconstructed); uniform: one rho_tilde (the paper)",
    )
    fit.add_argument(
        "--albedo-maps",
        type=Path,
        metavar="DIR",
        help="write DIR/NAME.npy per frame: float32 (H, W, 3) rho_tilde per pixel, NaN where "
        "not estimated",
    )
    fit.add_argument(
        "--max-tracks",
        type=_positive_int,
        metavar="N",
        help="with the albedo map: follow at most N surface points across frames (default "
        f"{DEFAULT_MAX_TRACKS}; more: steadier sigma and F_tilde on a reconstructed shape, "
        "slower)",
    )
    fit.add_argument(
        "--no-shading",
        action="store_true",
        help="images only: keep SfM's shape (refined by the texture) without refining it by "
        "the shading (faster; sigma and F_tilde then off by up to tens of percent)",
    )
    _add_mask_arguments(fit)
    fit.set_defaults(run=_cmd_fit)


def _diag_command(commands) -> None:
    diag = commands.add_parser(
        "diagnose", help="where the model fails, and which physical effect is missing"
    )
    diag.add_argument("capture", type=Path, help="capture folder (with depth)")
    diag.add_argument("--json", type=Path, required=True, help="output JSON file")
    diag.add_argument("--plots", type=Path, help="folder for residual maps and binned residuals")
    diag.add_argument(
        "--add",
        nargs="+",
        default=[],
        metavar="EFFECT",
        help="effects to add to the base model first (e.g. light_offset)",
    )
    diag.add_argument("--calib", type=int, help="number of calibration frames (default 60%%)")
    diag.add_argument(
        "--max-samples",
        type=_positive_int,
        default=12_000,
        metavar="N",
        help="calibration pixels (or tracked points, with the albedo map) each model is fitted "
        "on, a random subset (default %(default)s; fewer run faster)",
    )
    diag.add_argument(
        "--albedo",
        choices=("map", "uniform"),
        help="one albedo per surface point (map; the default when every frame has depth and a "
        "pose) or one for the capture (uniform, the paper's; then the albedo_texture "
        "candidate tries the map)",
    )
    diag.add_argument(
        "--loop",
        action="store_true",
        help="add the verdict to the base model and diagnose again, until the verdict is "
        "none (or --max-rounds steps); prints the held-out RMSE step by step",
    )
    diag.add_argument(
        "--max-rounds",
        type=_positive_int,
        default=5,
        metavar="N",
        help="--loop: at most this many diagnoses (default %(default)s)",
    )
    diag.set_defaults(run=_cmd_diagnose)


def _light_command(commands) -> None:
    light = commands.add_parser("calibrate-light", help="the laparoscope's light from images")
    light.add_argument("capture", type=Path, help="capture folder (with depth)")
    light.add_argument(
        "--model",
        choices=("near", "field"),
        default="near",
        help="near: point light offset from the lens; field: the paper's per-pixel "
        "light directions (eq. 7-8)",
    )
    light.add_argument("--json", type=Path, required=True, help="output JSON file")
    light.add_argument(
        "--npz",
        type=Path,
        help="field: output NPZ with the (H, W, 3) light directions, theta, phi, status",
    )
    _add_falloff_argument(light)
    light.add_argument(
        "--engine",
        choices=("optimistix", "closed-form"),
        default="optimistix",
        help="field: the per-pixel LM solver, optimistix's (the reference) or a batched 2x2 "
        "one written out (closed-form: several times faster)",
    )
    light.add_argument(
        "--albedo",
        choices=("map", "uniform"),
        help="one albedo per surface point (map; the default when every frame has depth and "
        "a pose) or one for the capture (uniform, the paper's)",
    )
    light.add_argument("--calib", type=int, help="number of calibration frames (default 60%%)")
    light.set_defaults(run=_cmd_calibrate_light)


def _evaluate_command(commands) -> None:
    evaluate = commands.add_parser(
        "evaluate", help="Lambertian vs Cook-Torrance: RGB error and shape from shading"
    )
    evaluate.add_argument("capture", type=Path, help="capture folder (with depth)")
    evaluate.add_argument("--json", type=Path, required=True, help="output JSON file")
    evaluate.add_argument("--plots", type=Path, help="folder for the paper's Fig. 4-7 plots")
    evaluate.add_argument("--calib", type=int, help="number of calibration frames (default 60%%)")
    evaluate.add_argument(
        "--light",
        choices=("near", "colocated", "field"),
        default="near",
        help="Cook-Torrance's light: near (point light offset), colocated (paper's BRDF fit "
        "with L = V) or field (the paper's per-pixel light field)",
    )
    evaluate.add_argument(
        "--albedo",
        choices=("map", "uniform"),
        help="one albedo per surface point for both models (map; the default when every "
        "frame has depth and a pose) or one per model (uniform, the paper's)",
    )
    evaluate.add_argument(
        "--per-pixel-sfs",
        action="store_true",
        help="also run the paper's Cook-Torrance SfS (Tsai-Shah's normals refined per pixel, "
        "eq. 9) and report it beside the joint one",
    )
    evaluate.add_argument(
        "--no-sfs",
        action="store_true",
        help="RGB errors only: no shape from shading (it needs depth with relief to score)",
    )
    evaluate.set_defaults(run=_cmd_evaluate)


def _batch_command(commands) -> None:
    from .batch import DEFAULT_STEPS, STEPS

    batch = commands.add_parser(
        "batch",
        help="many captures at once, on Dask",
        description="Runs the steps on every capture in parallel (dask.distributed: a local "
        "cluster of --workers processes, or an existing --scheduler); OUT/NAME/ gets the "
        "JSON files the single commands write, OUT/summary.csv and OUT/summary.html a row "
        "per capture. A failed capture is reported and the others go on; a rerun skips "
        "the captures already done (OUT/NAME/done.json).",
    )
    batch.add_argument("captures", type=Path, nargs="+", metavar="CAPTURE")
    batch.add_argument("--out", type=Path, required=True, help="results folder")
    batch.add_argument(
        "--steps",
        default=",".join(DEFAULT_STEPS),
        help=f"comma-separated, in order, from {', '.join(STEPS)}",
    )
    batch.add_argument(
        "--workers",
        type=int,
        default=2,
        help="local worker processes (0: one capture after the other, without Dask)",
    )
    batch.add_argument(
        "--scheduler", help="address of an existing Dask scheduler (e.g. tcp://host:8786)"
    )
    batch.set_defaults(run=_cmd_batch)


def _cmd_batch(args: argparse.Namespace) -> int:
    from .batch import run_batch

    if args.workers < 0:
        raise CtjaxError(f"--workers must be 0 or more, got {args.workers}")
    steps = [s.strip() for s in args.steps.split(",") if s.strip()]
    rows = run_batch(
        args.captures,
        args.out,
        steps,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=lambda m: print(f"[ctjax batch] {m}", flush=True),
    )
    failed = [row["capture"] for row in rows if row["status"] != "ok"]
    print(
        f"{len(rows) - len(failed)}/{len(rows)} capture(s) ok; wrote "
        f"{args.out / 'summary.csv'} and {args.out / 'summary.html'}"
    )
    if failed:
        print(f"ctjax batch: failed: {', '.join(failed)}", file=sys.stderr)
    return 0 if not failed else 1


def _add_falloff_argument(parser) -> None:
    parser.add_argument(
        "--falloff",
        default="auto",
        # ctjax.calibration._near_light.FALLOFF_NAMES (not imported here: it loads JAX)
        choices=("auto", "none", "inverse_square", "spot", "inverse_square+spot"),
        help="falloffs of the near light (auto: chosen on held-out frames)",
    )


def _demo_command(commands) -> None:
    demo = commands.add_parser("demo", help="the main job on a built-in synthetic capture")
    demo.add_argument("--out", default="ctjax-demo", help="output folder (default: ctjax-demo)")
    # texture contrast: ctjax.demo.DEMO_TEXTURE_CONTRAST (not imported here: it loads JAX)
    _add_synth_arguments(demo, frames=5, texture=True, texture_contrast=0.3)
    _add_falloff_argument(demo)
    demo.set_defaults(run=_cmd_demo)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit:  # bad options (status 2, one line), --help (status 0)
        return exit.code if isinstance(exit.code, int) else 0
    import jax

    from ._performance import enable_compilation_cache, tune_malloc, tune_xla

    # Estimation in double precision; renders stay in the dtype of their inputs.
    jax.config.update("jax_enable_x64", True)
    tune_malloc()
    tune_xla()
    enable_compilation_cache()
    try:
        return args.run(args)
    except CtjaxError as error:
        print(f"ctjax {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ctjax {args.command}: interrupted", file=sys.stderr)
        return 130


def run() -> None:
    """The `ctjax` console command: `main`, then the process ends without the interpreter's
    finalisation (`_exit`)."""
    _exit(main())


def _exit(code: int) -> None:
    """End the process with `code` once the `atexit` handlers have run (temporary folders,
    logging, Dask) and the outputs are flushed, skipping the interpreter's finalisation:
    with JAX loaded, tearing down its ~1000 modules and their objects takes 0.15-0.3 s on
    this project's 2-core machine, a seventh of a repeated `ctjax fit`. A command that
    leaves a non-daemon thread running exits normally (finalisation joins it)."""
    import atexit
    import os
    import threading

    running = [
        t
        for t in threading.enumerate()
        if t is not threading.main_thread() and not t.daemon and t.is_alive()
    ]
    run_exit_functions = getattr(atexit, "_run_exitfuncs", None)
    if running or run_exit_functions is None:
        sys.exit(code)
    run_exit_functions()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    os._exit(code)


if __name__ == "__main__":  # `python -m ctjax.cli`, as the `ctjax` command
    run()
