"""The shape refined by the shading (`ctjax.sfm._shading`) on captures from a renderer that
shares no code with ctjax, reconstructed from their images.

    python benchmarks/world_surface.py [--size 640x512] [--seeds 1 2] [--smoothing 10]
        [--iterations 10] [--max-points 8000]

Renders `tests/independent.py` captures (8 frames, per-channel texture, 1 level of noise),
reconstructs them from their images (`ctjax.sfm.reconstruct`, texture refinement included),
and prints the normals' error against the truth (median / 90th percentile, degrees) and the
albedo-map fit's sigma and F_tilde errors, before and after `refine_shape_by_shading`, with
the LM's own sigma, the cost and the time.
"""

import jax
import numpy as np

from ctjax.sfm._shading import ITERATIONS, MAX_POINTS, SMOOTHING, refine_shape_by_shading


def main():
    import argparse
    import sys
    import tempfile
    from pathlib import Path

    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from independent import Scene, _reconstructed, render_capture

    from ctjax.estimation import fit_capture
    from ctjax.io import load_capture

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="640x512")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--smoothing", type=float, default=SMOOTHING)
    parser.add_argument("--iterations", type=int, default=ITERATIONS)
    parser.add_argument("--max-points", type=int, default=MAX_POINTS)
    args = parser.parse_args()
    width, height = map(int, args.size.split("x"))
    scene = Scene()

    def figures(capture, truth):
        angles = []
        for true, frame in zip(truth.frames, capture.frames, strict=True):
            cosine = np.clip(np.sum(true.normals * frame.normals, -1), -1, 1)
            angle = np.degrees(np.arccos(cosine))
            angles.append(angle[np.isfinite(angle)])
        angles = np.concatenate(angles)
        fit = fit_capture(capture).to_json()
        return (
            f"normals {np.median(angles):.2f} / {np.percentile(angles, 90):.2f} deg, sigma "
            f"{100 * (fit['sigma'] / scene.sigma - 1):+.1f}%, F_tilde "
            f"{np.round(100 * (np.asarray(fit['F_tilde']) / scene.F - 1), 1).tolist()}%"
        )

    for seed in args.seeds:
        folder = Path(tempfile.mkdtemp(prefix="ctjax-world-surface-"))
        render_capture(folder, width, height, 8, seed, scene)
        truth = load_capture(folder)
        capture = load_capture(_reconstructed(folder, photometric=True))
        print(f"seed {seed} {args.size}: SfM + texture: {figures(capture, truth)}", flush=True)
        refined, report = refine_shape_by_shading(
            capture,
            smoothing=args.smoothing,
            iterations=args.iterations,
            max_points=args.max_points,
        )
        print(
            f"seed {seed} {args.size}: + shading: {figures(refined, truth)}; the LM's sigma "
            f"{100 * (report['sigma_after'] / scene.sigma - 1):+.1f}% on {report['points']} "
            f"points, {report['coefficients']} coefficients, cost {report['cost_before']:.4g} -> "
            f"{report['cost_after']:.4g}, {report['seconds']} s",
            flush=True,
        )


if __name__ == "__main__":
    main()
