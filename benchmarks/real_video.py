"""The whole chain on real endoscopic video, one table per sequence.

    .venv/bin/python benchmarks/real_video.py [SOURCE ...] [--frames 12] [--width 640]
        [--work DIR] [--skip-diagnose] [--skip-evaluate] [--max-rounds 4] [--focal refine]
        [--camera CALIBRATION] [--layout side-by-side|top-bottom] [--excluded MASKS]
        [--fit-effects EFFECT ...]

Each SOURCE is a capture folder (images/ and camera.json) or a video (imported with
`ctjax import`, a guessed pinhole camera: fx = fy = 0.8 width, the principal point at the
centre, unless a camera.json lies beside it). Without SOURCE: every sequence of
`../shared/real` (the sinus frames and the cholecystectomy video). Each is reduced to
`--frames` frames `--width` pixels wide, then run through the user guide's commands, as a user
would: `reconstruct` -> `masks` -> `fit` (and `fit` on the even and the odd frames apart:
is sigma stable across frame subsets?) -> `calibrate-light` (near) -> `evaluate` ->
`diagnose --loop`; `fit` fits a gain per frame where the frames' brightness moves its lobe
(a scope's auto-exposure), `--fit-effects frame_exposure` always and `--fit-effects none`
never, in `fit` and its even / odd frames. It prints, per sequence:

- masks: S's share of the field of view, and the recall of the near-white cores (every
  channel >= 230 recorded, away from the rim of the field of view) with S's area over
  those cores dilated by 7x7 pixels (the goal: recall >= 95%, area <= 3x);
- SfM: registered frames, points, reprojection error, coverage, frames whose texture
  refinement was kept; and from which level each channel reads as clipped (below 1: the
  camera's ceiling, `Capture.saturation`);
- fit: sigma, F_tilde, their standard errors and the status, on all, even and odd frames
  (and, on a stereo capture, with the right camera's views: `fit --right-views`);
- the near light: falloff, offset (with its unit), status;
- evaluate: Cook-Torrance against Lambertian on the held-out frames, the gain split into
  the light's and the lobe's (and on a stereo capture both on the right camera's views),
  and the lobe about every point's own facet where `evaluate` judges it (`--facets auto`),
  with the best determined lobe (`lobes_judged`);
- diagnose --loop: the held-out RMSE step by step against the noise floor, and what is left
  of the last model's residual (`residual_budget`).

Slow (minutes per sequence on 2 cores): a benchmark, not a test.
"""

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from _results import emit

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "real"
CTJAX = [sys.executable, "-m", "ctjax.cli"]
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".m4v")


def _run(argv, log: Path) -> tuple[int, float]:
    started = time.perf_counter()
    with open(log, "w") as out:
        status = subprocess.run(
            [*CTJAX, *map(str, argv)], stdout=out, stderr=subprocess.STDOUT, cwd=ROOT
        ).returncode
    return status, time.perf_counter() - started


def _json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def prepare(
    source: Path, out: Path, frames: int, width: int, camera=None, layout=(), excluded=None
) -> Path:
    """A capture of `frames` frames, `width` px wide, from a capture folder or a video
    (`camera`: its calibration, camera.json, OpenCV's file or a da Vinci's .ini; `layout`:
    import's stereo flag, e.g. ("--top-bottom",); `excluded`: the video's instrument masks,
    import's --excluded; a capture folder carries its own excluded/)."""
    source = source.resolve()  # the commands run from the repository's root
    capture = out / "capture"
    if capture.is_dir():
        shutil.rmtree(capture)
    out.mkdir(parents=True, exist_ok=True)
    if source.suffix.lower() in VIDEO_SUFFIXES:
        camera = camera.resolve() if camera is not None else source.with_name("camera.json")
        if not camera.is_file():
            video = cv2.VideoCapture(str(source))
            w, h = video.get(cv2.CAP_PROP_FRAME_WIDTH), video.get(cv2.CAP_PROP_FRAME_HEIGHT)
            video.release()
            camera = out / "guessed_camera.json"
            guess = {"width": int(w), "height": int(h), "fx": 0.8 * w, "fy": 0.8 * w}
            camera.write_text(json.dumps(guess | {"cx": (w - 1) / 2, "cy": (h - 1) / 2}))
        argv = ["import", source, "--camera", camera, "--out", capture, *layout]
        if excluded is not None:
            argv += ["--excluded", excluded.resolve()]
        status, _ = _run([*argv, "--max-frames", frames, "--width", width], out / "import.log")
        if status:
            raise SystemExit(f"{source}: ctjax import failed (see {out / 'import.log'})")
        return capture
    names = sorted(
        p for p in (source / "images").iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg")
    )
    step = max(1, len(names) // frames)
    camera = json.loads((source / "camera.json").read_text())
    scale = width / camera["width"]
    stereo = camera.get("stereo")
    (capture / "images").mkdir(parents=True)
    if stereo is not None:  # a stereo capture: its right images too, scaled alike
        (capture / "right").mkdir()
    for path in names[::step][:frames]:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(capture / "images" / f"{path.stem}.png"), image)
        if stereo is not None:
            right = cv2.imread(str(next((source / "right").glob(f"{path.stem}.*"))))
            right = cv2.resize(right, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(capture / "right" / f"{path.stem}.png"), right)
        for folder in ("excluded", "excluded/right"):  # an instrument's pixels, shrunk alike
            for mask_path in (source / folder).glob(f"{path.stem}.*"):
                mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
                mask = cv2.resize(mask, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
                (capture / folder).mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(capture / folder / f"{path.stem}.png"), (mask > 0) * np.uint8(255))
    for mask_path in source.glob("excluded.*"):  # pixels excluded in every frame, shrunk
        mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
        mask = cv2.resize(mask, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(capture / "excluded.png"), (mask > 0) * np.uint8(255))
    camera |= _scaled(camera, scale) | {"width": image.shape[1], "height": image.shape[0]}
    if stereo is not None:
        right = stereo["right"]
        size = {k: round(right[k] * scale) for k in ("width", "height") if k in right}
        camera["stereo"] = stereo | {"right": right | _scaled(right, scale) | size}
    (capture / "camera.json").write_text(json.dumps(camera))
    return capture


def _scaled(camera: dict, scale: float) -> dict:
    """A pinhole camera's intrinsics for images resized by `scale` (pixel centres kept)."""
    return {
        "fx": camera["fx"] * scale,
        "fy": camera["fy"] * scale,
        "cx": (camera["cx"] + 0.5) * scale - 0.5,
        "cy": (camera["cy"] + 0.5) * scale - 0.5,
    }


def subset(capture: Path, out: Path, parity: int) -> Path:
    """The even (0) or odd (1) frames of a reconstructed capture, as a capture."""
    if out.is_dir():
        shutil.rmtree(out)
    names = sorted(p.stem for p in (capture / "images").iterdir())[parity::2]
    for folder in ("images", "depth", "normals", "right", "excluded", "excluded/right"):
        if not (capture / folder).is_dir():
            continue  # "right": a stereo capture's only; "excluded": where instruments are
        (out / folder).mkdir(parents=True)
        for path in (capture / folder).iterdir():
            if path.is_file() and path.stem in names:
                shutil.copy(path, out / folder / path.name)
    for name in ("camera.json", "reconstruction.json"):
        shutil.copy(capture / name, out / name)
    for path in capture.glob("excluded.*"):  # pixels excluded in every frame
        shutil.copy(path, out / path.name)
    poses = _json(capture / "poses.json")
    (out / "poses.json").write_text(json.dumps({k: v for k, v in poses.items() if k in names}))
    return out


def highlight_figures(capture: Path, masks: Path) -> dict:
    """S's share of the field of view; recall of the near-white cores (every channel >= 230
    recorded, inside the field of view eroded by 2% of the width) and S's area over the
    cores dilated by 7x7."""
    cores = dilated = found = s_area = fov_area = 0
    erode = np.ones((2 * max(1, round(0.01 * _width(capture))) + 1,) * 2, np.uint8)
    for path in sorted((masks / "specular").iterdir()):
        image = cv2.imread(str(next((capture / "images").glob(f"{path.stem}.*"))))
        specular = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127
        fov = cv2.imread(str(masks / "fov" / path.name), cv2.IMREAD_GRAYSCALE) > 127
        inner = cv2.erode(fov.astype(np.uint8), erode) > 0
        core = np.all(image >= 230, axis=-1) & inner
        cores += int(core.sum())
        found += int((core & specular).sum())
        dilated += int((cv2.dilate(core.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0).sum())
        s_area += int(specular.sum())
        fov_area += int(fov.sum())
    return {
        "S_share_of_fov": s_area / max(fov_area, 1),
        "core_pixels": cores,
        "core_recall": found / cores if cores else None,
        "S_over_dilated_cores": s_area / dilated if dilated else None,
    }


def _width(capture: Path) -> int:
    return json.loads((capture / "camera.json").read_text())["width"]


def _lobe(fit: dict) -> dict:
    keys = ("sigma", "sigma_stderr", "F_tilde", "F_tilde_stderr", "status", "rgb_rmse")
    out = {k: fit.get(k) for k in keys}
    out["undetermined"] = [u["parameter"] for u in fit.get("undetermined", [])]
    out["lambertian_rmse"] = fit.get("lambertian", {}).get("rgb_rmse")
    # How much the frames' own normals of one surface point disagree (fit uses their mean).
    out["frames_disagree_deg"] = fit.get("normals", {}).get("frames_disagree_deg")
    return out


def run_sequence(source: Path, work: Path, args) -> dict:
    out = work / source.stem
    out.mkdir(parents=True, exist_ok=True)
    seconds = {}
    layout = [f"--{args.layout}"] if args.layout else []
    capture = prepare(source, out, args.frames, args.width, args.camera, layout, args.excluded)
    recon = out / "reconstructed"
    if recon.is_dir():
        shutil.rmtree(recon)
    reconstruct = ["reconstruct", capture, "--out", recon]
    fit_effects = ["--effects", *args.fit_effects] if args.fit_effects else []
    steps = [
        ("reconstruct", [*reconstruct, "--json", out / "recon.json", "--focal", args.focal]),
        ("masks", ["masks", recon, "--out", out / "masks"]),
        ("fit", ["fit", recon, "--json", out / "fit.json", *fit_effects]),
        ("light", ["calibrate-light", recon, "--model", "near", "--json", out / "light.json"]),
    ]
    if (capture / "right").is_dir():  # stereo: the right views fitted too
        right = ["fit", recon, "--right-views", "--json", out / "fit_right.json"]
        steps.insert(3, ("fit_right", right))
    if not args.skip_evaluate:
        steps.append(("evaluate", ["evaluate", recon, "--json", out / "evaluate.json", "--no-sfs"]))
    if not args.skip_diagnose:
        loop = ["--loop", "--max-rounds", args.max_rounds, "--plots", out / "diagnose"]
        steps.append(("diagnose", ["diagnose", recon, "--json", out / "diagnose.json", *loop]))
    failed = {}
    for name, argv in steps:
        print(f"  {source.stem}: {name}...", flush=True)
        status, seconds[name] = _run(argv, out / f"{name}.log")
        if status:
            failed[name] = f"exit {status} (see {out / f'{name}.log'})"
            if name == "reconstruct":
                break
    for parity, label in ((0, "even"), (1, "odd")):
        if "reconstruct" in failed:
            break
        half = subset(recon, out / f"{label}_frames", parity)
        status, seconds[f"fit_{label}"] = _run(
            ["fit", half, "--json", out / f"fit_{label}.json", *fit_effects],
            out / f"fit_{label}.log",
        )
    return _table(source, out, capture, seconds, failed)


def _table(source, out, capture, seconds, failed) -> dict:
    recon = _json(out / "recon.json")
    photometric = recon.get("surface", {}).get("photometric", {})
    light, evaluation = _json(out / "light.json"), _json(out / "evaluate.json")
    diagnosis = _json(out / "diagnose.json")
    row = {
        "sequence": str(source),
        "frames": recon.get("frames"),
        "size": f"{_width(capture)} px wide",
        "masks": highlight_figures(capture, out / "masks") if (out / "masks").is_dir() else None,
        "sfm": {
            "registered": len(recon.get("registered", [])),
            "points": recon.get("points"),
            "reprojection_px": recon.get("mean_reprojection_error_px"),
            "coverage": recon.get("coverage"),
            "texture_refinement_kept": photometric.get("kept_frames"),
            "length_unit": recon.get("length_unit"),
        },
        # Per channel, from which level the observations read as clipped (the camera's
        # ceiling where below 1).
        "saturation": _json(out / "fit.json").get("saturation"),
        "fit": _lobe(_json(out / "fit.json")),
        "fit_even": _lobe(_json(out / "fit_even.json")),
        "fit_odd": _lobe(_json(out / "fit_odd.json")),
        "fit_right": _lobe(_json(out / "fit_right.json")),
        "near_light": {
            "falloff": "+".join(light.get("falloff", {})) or "none",
            "offset": light.get("offset_mm", light.get("offset")),
            "offset_unit": light.get("length_unit"),
            "status": light.get("status"),
            "F_tilde": light.get("F_tilde"),
            "sigma": light.get("sigma"),
            "heldout_rmse": light.get("rgb_rmse_heldout"),
            "noise_floor": light.get("noise_floor"),
        },
        "evaluate": {
            k: evaluation.get(k)
            for k in (
                "lambertian_rgb_rmse_test",
                "lambertian_same_light_rgb_rmse_test",
                "cook_torrance_rgb_rmse_test",
                "gain",
                "right_views",
                "facets",
                "lobes_judged",
            )
        },
        "diagnose": [
            {k: s[k] for k in ("added_before", "base_rmse", "noise_floor", "verdict", "seconds")}
            for s in diagnosis.get("loop", {}).get("steps", [])
        ],
        "diagnose_stopped": diagnosis.get("loop", {}).get("stopped"),
        "residual_budget": diagnosis.get("residual_budget"),
        "failed": failed,
        "seconds": {k: round(v, 1) for k, v in seconds.items()},
    }
    _print(row)
    return row


def _fmt(value, digits=3) -> str:
    if value is None:
        return "-"
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v, digits) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _print(row: dict) -> None:
    print(f"\n== {row['sequence']} ({row['frames']} frames, {row['size']})")
    m = row["masks"] or {}
    print(
        f"masks      S {_fmt(m.get('S_share_of_fov'))} of the field of view; near-white cores "
        f"{m.get('core_pixels')} px, recall {_fmt(m.get('core_recall'))}, S / dilated cores "
        f"{_fmt(m.get('S_over_dilated_cores'))} (goal: recall >= 0.95, <= 3)"
    )
    s = row["sfm"]
    print(
        f"SfM        {s['registered']}/{row['frames']} registered, {s['points']} points, "
        f"reprojection {_fmt(s['reprojection_px'])} px, coverage {_fmt(s['coverage'])}, "
        f"texture refinement kept in {s['texture_refinement_kept']} frames, unit "
        f"{s['length_unit']}; the frames' normals of one point disagree by "
        f"{_fmt(row['fit']['frames_disagree_deg'])} deg RMS; clipped from (linear R, G, B) "
        f"{_fmt(row['saturation'])}"
    )
    for key in ("fit", "fit_even", "fit_odd", "fit_right"):
        f = row[key]
        if key == "fit_right" and f["sigma"] is None:
            continue  # not a stereo sequence
        print(
            f"{key:<10} sigma {_fmt(f['sigma'], 4)} +- {_fmt(f['sigma_stderr'], 2)}, F_tilde "
            f"{_fmt(f['F_tilde'])} +- {_fmt(f['F_tilde_stderr'], 2)}, status {f['status']}; "
            f"RMSE {_fmt(f['rgb_rmse'])} vs Lambertian {_fmt(f['lambertian_rmse'])} levels"
        )
    n = row["near_light"]
    print(
        f"near light falloff {n['falloff']}, offset {_fmt(n['offset'])} {n['offset_unit']}, "
        f"F_tilde {_fmt(n['F_tilde'])}, sigma {_fmt(n['sigma'])}, status {n['status']}; "
        f"held-out {_fmt(n['heldout_rmse'])} levels, noise floor {_fmt(n['noise_floor'])}"
    )
    e = row["evaluate"]
    gain = e.get("gain") or {}
    print(
        f"evaluate   test RMSE Lambertian {_fmt(e['lambertian_rgb_rmse_test'])}, under the same "
        f"light {_fmt(e['lambertian_same_light_rgb_rmse_test'])}, Cook-Torrance "
        f"{_fmt(e['cook_torrance_rgb_rmse_test'])} levels (light {_fmt(gain.get('light_levels'))}"
        f", lobe {_fmt(gain.get('lobe_levels'))})"
    )
    facets = e.get("facets")
    if facets:  # judged by `evaluate --facets auto` where the highlights hold the residual
        print(
            f"facets     sigma {_fmt(facets['sigma'])}, F_tilde {_fmt(facets['F_tilde'])}, "
            f"status {facets['status']}; test RMSE {_fmt(facets['heldout_rgb_rmse'])}, "
            f"{_fmt(facets['ratio'])}x Lambertian under the same light"
        )
    judged = e.get("lobes_judged") or {}
    if len(judged.get("lobes", [])) > 1:
        print(f"lobes      the best determined: {judged['best_determined'] or 'none'}")
    right = e.get("right_views")
    if right:
        figures = ", ".join(
            f"{name} {_fmt(value['right'])} / {_fmt(value['left'])}"
            for name, value in right.items()
            if name.endswith("_rgb_rmse")
        )
        print(f"right views {right['views']} views, right / left RMSE: {figures}")
    for k, step in enumerate(row["diagnose"]):
        added = " + ".join(["paper", *step["added_before"]])
        print(
            f"diagnose {k + 1} {added}: held-out {_fmt(step['base_rmse'])} levels, floor "
            f"{_fmt(step['noise_floor'])} ({_fmt(step['base_rmse'] / step['noise_floor'])}x), "
            f"verdict {step['verdict']} ({_fmt(step['seconds'])} s)"
        )
    if row["diagnose_stopped"]:
        print(f"diagnose   stopped: {row['diagnose_stopped']}")
    budget = row["residual_budget"]
    if budget and "rmse_levels" in budget:
        variable, smooth = max(budget["smooth_share"].items(), key=lambda item: item[1])
        print(
            f"left       {_fmt(budget['rmse_levels'])} levels: gradient "
            f"{_fmt(100 * budget['gradient_share'])}% ({_fmt(budget['misregistration_px'])} px), "
            f"near S {_fmt(100 * budget['highlight_share'])}% (on "
            f"{_fmt(100 * budget['highlight_pixels'])}% of the pixels, "
            f"{_fmt(budget['highlight_excess_levels'])} levels brighter than the model), "
            f"gain per frame "
            f"{_fmt(100 * budget['per_frame_share'])}%, {variable} {_fmt(100 * smooth)}%"
        )
    for name, why in row["failed"].items():
        print(f"FAILED     {name}: {why}")
    print(f"seconds    {row['seconds']}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sources", nargs="*", type=Path)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--work", type=Path, default=Path("/tmp/ctjax-real-video"))
    parser.add_argument(
        "--focal",
        choices=("fixed", "refine"),
        default="fixed",
        help="reconstruct's --focal (refine: the guessed camera's focal length from the frames)",
    )
    parser.add_argument(
        "--camera",
        type=Path,
        help="a video's calibration: camera.json, OpenCV's file (SCARED's "
        "endoscope_calibration.yaml) or a da Vinci's StereoCalibration.ini (StereoMIS's; "
        "default: camera.json beside the video, else a guess)",
    )
    parser.add_argument(
        "--excluded",
        type=Path,
        help="a video's instrument masks, a video or folder frame for frame with it "
        "(import's --excluded)",
    )
    parser.add_argument(
        "--layout",
        choices=("side-by-side", "top-bottom"),
        help="a stereo video's frames hold both images (SCARED's rgb.mp4: top-bottom)",
    )
    parser.add_argument(
        "--fit-effects",
        nargs="+",
        default=[],
        metavar="EFFECT",
        help="image effects fitted in fit and its even / odd frames (fit's --effects)",
    )
    parser.add_argument("--max-rounds", type=int, default=4)
    parser.add_argument("--skip-diagnose", action="store_true")
    parser.add_argument("--skip-evaluate", action="store_true")
    args = parser.parse_args(argv)
    sources = args.sources
    if not sources:
        if not SHARED.is_dir():
            raise SystemExit(f"{SHARED} not found: give capture folders or videos")
        sources = [SHARED / "jhu-sinus-a", *sorted(SHARED.glob("*/*.mp4"))]
    for source in sources:
        emit(run_sequence(source, args.work, args))


if __name__ == "__main__":
    main()
