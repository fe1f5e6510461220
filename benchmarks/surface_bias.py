"""What the depth surface alone costs the near light: each frame's P-spline fitted to exact
depths, then `calibrate-light` on its normals.

`reconstruct` represents each view's depth by a P-spline (`ctjax.sfm._surface`: knots
`max(W, H) / 20` px apart, a thin-plate penalty chosen by cross-validation), fitted to
SfM's points and then refined by the texture. This benchmark takes the synthetic stereo
capture of `benchmarks/near_light_stereo.py` (`ctjax synth --stereo 5 --light-offset 4 -3 0
--inverse-square`), fits the same spline to POINTS pixels of each frame's *true* depth (no
noise, the true poses), writes its depth and normals into a copy of the capture, and
calibrates the near light on the truth and on that copy. Prints, per seed, the median
normal error, the tilt toward the optical axis in the steepest quarter of the true normals
(negative: flatter than the truth), split at BORDER px from the image's edge, and the
offset's distance from the truth (calibrate-light's final offset).

    python benchmarks/surface_bias.py --seeds 0 2
    python benchmarks/surface_bias.py --seeds 0 --points 20000 --knot-px 8
"""

import argparse
import shutil
import tempfile
from pathlib import Path

import jax
import numpy as np

TRUE_OFFSET_MM = (4.0, -3.0, 0.0)


def _tilts(frames, normals_of, border: int) -> tuple[float, float, float, float]:
    """Median normal error (deg), and the steepest quarter's median tilt toward the axis
    (deg): all of it, within `border` px of the image's edge, and inside."""
    errors, steep, near, inside = [], [], [], []
    for frame in frames:
        est, true = normals_of(frame).astype(float), frame.normals.astype(float)
        ok = np.all(np.isfinite(est), -1) & np.all(np.isfinite(true), -1) & frame.geometry_mask
        h, w = ok.shape
        v, u = np.mgrid[0:h, 0:w]
        edge = np.minimum(np.minimum(u, w - 1 - u), np.minimum(v, h - 1 - v)) < border
        cosine = np.clip(np.sum(est * true, -1), -1, 1)
        errors.append(np.median(np.degrees(np.arccos(cosine))[ok]))
        axis = np.array([0.0, 0.0, -1.0])
        polar_true = np.degrees(np.arccos(np.clip(true @ axis, -1, 1)))
        polar_est = np.degrees(np.arccos(np.clip(est @ axis, -1, 1)))
        quarter = ok & (polar_true >= np.quantile(polar_true[ok], 0.75))
        tilt = polar_est - polar_true
        steep.append(np.median(tilt[quarter]))
        near.append(np.median(tilt[quarter & edge]) if (quarter & edge).any() else np.nan)
        inside.append(np.median(tilt[quarter & ~edge]) if (quarter & ~edge).any() else np.nan)
    return tuple(float(np.nanmean(x)) for x in (errors, steep, near, inside))


def run(seed: int, width: int, height: int, frames: int, points: int, knot_px, border, work):
    from ctjax.calibration import calibrate_near_light
    from ctjax.io import load_capture
    from ctjax.lights import InverseSquare
    from ctjax.sfm._reconstruct import ViewSurface
    from ctjax.sfm._surface import fit_depth_surface
    from ctjax.synth import SynthOptions, synthesize

    effects = {"light_offset": TRUE_OFFSET_MM, "inverse_square": True}
    options = SynthOptions(
        width=width, height=height, frames=frames, seed=seed, stereo_mm=5.0, effects=effects
    )
    truth = synthesize(work / "truth", options)
    capture = load_capture(truth)
    camera = capture.camera
    knot = max(width, height) / 20 if knot_px is None else knot_px
    rng = np.random.default_rng(seed)
    spline = work / "spline"
    shutil.copytree(truth, spline)
    surfaces = {}
    for frame in capture.frames:
        ok = frame.geometry_mask & np.isfinite(frame.depth)
        rows, cols = np.nonzero(ok)
        pick = rng.choice(rows.size, min(points, rows.size), replace=False)
        u, v = cols[pick].astype(float), rows[pick].astype(float)
        z = frame.depth[rows[pick], cols[pick]].astype(float)
        bounds = (-knot, width - 1 + knot, -knot, height - 1 + knot)  # as reconstruct
        surface = fit_depth_surface(u, v, z, bounds, knot_spacing_px=knot)
        view = ViewSurface(frame.name, surface, ok, np.asarray(frame.pose, float), pick.size)
        depth, normals = view.depth_and_normals(camera)
        np.save(spline / "depth" / f"{frame.name}.npy", depth)
        np.save(spline / "normals" / f"{frame.name}.npy", normals)
        surfaces[frame.name] = normals
    tilts = _tilts(capture.frames, lambda f: surfaces[f.name], border)
    off = lambda p: float(np.linalg.norm(np.asarray(p) - TRUE_OFFSET_MM))  # noqa: E731
    light = (InverseSquare(70.0),)
    offsets = [
        off(calibrate_near_light(load_capture(c), falloff=light).to_json()["offset_mm"])
        for c in (truth, spline)
    ]
    return tilts, offsets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="320x256")
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 2])
    parser.add_argument("--points", type=int, default=1600, help="exact depths per frame")
    parser.add_argument("--knot-px", type=float, default=None)
    parser.add_argument("--border", type=int, default=16)
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    width, height = map(int, args.size.split("x"))
    print(
        f"{args.size} x {args.frames}, {args.points} exact depths per frame, knots "
        f"{args.knot_px or max(width, height) / 20:g} px, light at {TRUE_OFFSET_MM} mm"
    )
    print(
        "seed | normals' median error deg | steepest quarter's tilt deg (all / within "
        f"{args.border} px of the edge / inside) | offset mm off: true shape / spline"
    )
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as folder:
            (error, steep, near, inside), (true_mm, spline_mm) = run(
                seed,
                width,
                height,
                args.frames,
                args.points,
                args.knot_px,
                args.border,
                Path(folder),
            )
        print(
            f"{seed} | {error:.3f} | {steep:+.3f} / {near:+.3f} / {inside:+.3f} | "
            f"{true_mm:.2f} / {spline_mm:.2f}"
        )


if __name__ == "__main__":
    main()
