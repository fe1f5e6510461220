"""The near light in millimetres on synthetic stereo captures, with the shape and the light
fitted together (`ctjax reconstruct --shading near`), or on the shape from the images alone
(`--shading none`).

For each seed: `ctjax synth --stereo 5 --light-offset 4 -3 0 --inverse-square` (W x H x N),
the images alone reconstructed (depth in mm from the pairs), the shape refined by the
shading jointly with a point light's position, then `calibrate-light --falloff
inverse_square` on the refined shape. Prints, per seed, the distance of each position from
the truth (the refinement's; calibrate-light's on the calibration frames, and its final one
from every frame, beside half the difference of the even and the odd frames' fits and the
offset's change with every normal tilted 0.5 degrees, `offset_normal_tilt`), sigma, and the
depth's median relative error.

    python benchmarks/near_light_stereo.py --size 320x256 --frames 8 --seeds 1 2 3 4
    python benchmarks/near_light_stereo.py --shading none --frames 8 --seeds 1 2 3
    python benchmarks/near_light_stereo.py --shading none --frames 5 --seeds 0 --texture-smoothing 2
    python benchmarks/near_light_stereo.py --shading none --frames 5 --seeds 0 1 2 3 --offset free
"""

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

TRUE_OFFSET_MM = (4.0, -3.0, 0.0)


def _images_only(capture: Path, out: Path) -> Path:
    out.mkdir(parents=True)
    shutil.copy(capture / "camera.json", out / "camera.json")
    for folder in ("images", "right"):
        shutil.copytree(capture / folder, out / folder)
    return out


def run(
    width: int,
    height: int,
    frames: int,
    seed: int,
    work: Path,
    shading: str,
    smoothing=None,
    offset_axes: str = "lens_plane",
) -> dict:
    from ctjax.calibration import calibrate_near_light
    from ctjax.io import load_capture
    from ctjax.lights import InverseSquare
    from ctjax.sfm import reconstruct
    from ctjax.synth import SynthOptions, synthesize

    effects = {"light_offset": TRUE_OFFSET_MM, "inverse_square": True}
    options = SynthOptions(
        width=width, height=height, frames=frames, seed=seed, stereo_mm=5.0, effects=effects
    )
    truth = synthesize(work / "truth", options)
    started = time.perf_counter()
    images = _images_only(truth, work / "images")
    shading = False if shading == "none" else shading
    report = reconstruct(images, work / "refined", shading=shading, texture_smoothing=smoothing)
    seconds = time.perf_counter() - started
    shading = report["surface"].get("shading", {"refined": True})
    refined = load_capture(work / "refined")
    depth_error = [
        float(np.median(e.depth[ok] / t.depth[ok] - 1))
        for t, e in zip(load_capture(truth).frames, refined.frames, strict=True)
        for ok in [np.isfinite(t.depth) & np.isfinite(e.depth)]
    ]
    falloff = (InverseSquare(70.0),)
    light = calibrate_near_light(refined, falloff=falloff, offset_axes=offset_axes).to_json()
    off = lambda p: float(np.linalg.norm(np.asarray(p) - TRUE_OFFSET_MM))  # noqa: E731
    return {
        "refined": shading["refined"],
        "joint_mm": off(shading["light"]["position_mm"]) if "light" in shading else None,
        "joint_sigma": shading.get("sigma_after", np.nan),
        "calibrated_mm": off(light["offset_fitted_mm"]),
        "final_mm": off(light["offset_mm"]),
        "halves_mm": float(np.linalg.norm(light.get("offset_halves_stderr_mm", np.nan))),
        "tilt_mm": float(np.linalg.norm(light.get("offset_per_normal_tilt_mm", np.nan))),
        "calibrated_sigma": light["sigma"],
        "depth_error": max(depth_error, key=abs),
        "seconds": seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="320x256")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--shading", choices=("near", "none"), default="near")
    parser.add_argument("--texture-smoothing", type=float, default=None)
    parser.add_argument(
        "--offset",
        choices=("lens-plane", "free"),
        default="lens-plane",
        help="calibrate-light's --offset: the light in the lens plane, or along the axis too",
    )
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    width, height = map(int, args.size.split("x"))
    print(f"{args.size} x {args.frames}, light at {TRUE_OFFSET_MM} mm, inverse square")
    print(
        "seed | joint mm | joint sigma | calibrated mm | final mm (even / odd; normals) | "
        "calibrated sigma | depth | s"
    )
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as folder:
            r = run(
                width,
                height,
                args.frames,
                seed,
                Path(folder),
                args.shading,
                args.texture_smoothing,
                args.offset.replace("-", "_"),
            )
        joint = "-" if r["joint_mm"] is None else f"{r['joint_mm']:.2f}"
        print(
            f"{seed} | {joint} | {r['joint_sigma']:.3f} | {r['calibrated_mm']:.2f} | "
            f"{r['final_mm']:.2f} ({r['halves_mm']:.2f}; {r['tilt_mm']:.2f}) | "
            f"{r['calibrated_sigma']:.3f} | {r['depth_error']:+.2%} | {r['seconds']:.0f}"
            + ("" if r["refined"] else " (refinement not kept)")
        )


if __name__ == "__main__":
    main()
