"""Where the BRDF's error comes from when the shape comes from images: SfM's normals, its
depth (the correspondence between frames) or its poses; and what the texture refinement of
the surfaces (`ctjax.sfm._photometric`) buys.

    .venv/bin/python benchmarks/sfm_bias.py [--out DIR] [--frames 5 --width 320 --height 256]
        [--seed 0] [--texture-smoothing X]

Synthesises the demo's capture (textured, 1 level of noise), reconstructs it from its images
alone (`ctjax.sfm.reconstruct`, metric scale from the true working distance as the demo
does; with the texture refinement, the default, and without it: "points only"), then fits
the BRDF with the albedo map (`fit_capture`) on the true geometry, on SfM's, and on hybrids
that take one ingredient from each: normals, depth and poses. Prints sigma's and F_tilde's
relative errors per hybrid, and SfM's normal errors (degrees) over all pixels and over the
bright ones (within 90% of the frame's brightest), where the lobe is measured; and, near the
highlights' peaks, how much SfM's normals widen the lobe: the mean excess of tan^2 of the
angle between normal and view, as a widening of sigma.
"""

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from _results import emit

from ctjax.estimation import fit_capture
from ctjax.io import load_capture
from ctjax.sfm import reconstruct
from ctjax.synth import SynthOptions, synthesize

# (name, normals from, depth from, poses from): "t" the truth, "s" SfM refined by the
# texture (`ctjax reconstruct`'s default), "p" SfM's points only (--no-photometric).
HYBRIDS = (
    ("truth", "t", "t", "t"),
    ("sfm", "s", "s", "s"),
    ("sfm points only", "p", "p", "p"),
    ("sfm depth+poses, true normals", "t", "s", "s"),
    ("true depth+poses, sfm normals", "s", "t", "t"),
    ("true depth+poses, points-only normals", "p", "t", "t"),
    ("true depth+normals, sfm poses", "t", "t", "s"),
)


def _hybrid(root: Path, sources: dict, normals: str, depth: str, poses: str) -> Path:
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    shutil.copy(sources["s"] / "camera.json", root)
    shutil.copytree(sources["s"] / "images", root / "images")
    shutil.copytree(sources[normals] / "normals", root / "normals")
    shutil.copytree(sources[depth] / "depth", root / "depth")
    shutil.copy(sources[poses] / "poses.json", root / "poses.json")
    return root


def _tan2_to_view(camera, normals) -> np.ndarray:
    """tan^2 of the angle between each pixel's normal and its view direction: with the light
    at the camera, the Beckmann exponent's tan^2 of the half-vector angle."""
    h, w = normals.shape[:2]
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    x = (u - float(camera.cx)) / float(camera.fx)
    y = (v - float(camera.cy)) / float(camera.fy)
    ray = np.stack([x, y, np.ones_like(u)], -1)
    cosine = -np.sum(normals * ray, -1) / np.linalg.norm(ray, axis=-1)
    return (1 - cosine**2) / cosine**2


def _normal_errors(truth, sfm) -> dict:
    """SfM's normal errors (degrees) over all pixels and the bright ones, and near the
    highlights' peaks (true tan(angle N-V) < 0.1) the mean excess of SfM's tan^2: an error
    in the normal always widens the lobe there, as sigma^2 -> sigma^2 + excess would."""
    everywhere, bright, excess = [], [], []
    for true_frame, frame in zip(truth.frames, sfm.frames, strict=True):
        cosine = np.clip(np.sum(true_frame.normals * frame.normals, -1), -1, 1)
        angle = np.degrees(np.arccos(cosine))
        ok = np.isfinite(angle)
        lum = true_frame.image.max(-1)
        everywhere.append(angle[ok])
        bright.append(angle[ok & (lum > 0.9 * lum.max())])
        true_tan2 = _tan2_to_view(truth.camera, true_frame.normals)
        sfm_tan2 = _tan2_to_view(truth.camera, frame.normals)
        peak = ok & (true_tan2 < 0.01) & np.isfinite(sfm_tan2)
        excess.append(sfm_tan2[peak] - true_tan2[peak])
    everywhere, bright = np.concatenate(everywhere), np.concatenate(bright)
    excess = float(np.mean(np.concatenate(excess)))
    sigma = float(truth.truth["sigma"])
    return {
        "normal_median_deg": round(float(np.median(everywhere)), 2),
        "normal_bright_median_deg": round(float(np.median(bright)), 2),
        "normal_bright_p90_deg": round(float(np.percentile(bright, 90)), 2),
        "peak_tan2_excess": round(excess, 5),
        "peak_sigma_widening_pct": round(100 * (float(np.sqrt(1 + excess / sigma**2)) - 1), 1),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=256)
    parser.add_argument("--texture-contrast", type=float, default=0.3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--texture-smoothing", type=float, default=None)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="ctjax-sfm-bias-"))
    options = SynthOptions(
        frames=args.frames,
        width=args.width,
        height=args.height,
        texture_contrast=args.texture_contrast,
        seed=args.seed,
    )
    truth_dir = synthesize(out / "truth", options)
    truth = load_capture(truth_dir)
    first = truth.frames[0]
    scale_mm = float(np.nanmedian(first.depth[first.geometry_mask]))
    sources = {"t": truth_dir}
    row = {"benchmark": "sfm_bias", "size": f"{args.width}x{args.height}", "frames": args.frames}
    for key, name, photometric in (("s", "sfm", True), ("p", "sfm_points_only", False)):
        sources[key] = sfm_dir = out / name
        shutil.rmtree(sfm_dir, ignore_errors=True)
        (sfm_dir / "images").mkdir(parents=True)
        shutil.copy(truth_dir / "camera.json", sfm_dir)
        for image in sorted((truth_dir / "images").iterdir()):
            shutil.copy(image, sfm_dir / "images" / image.name)
        started = time.perf_counter()
        smoothing = args.texture_smoothing if photometric else None
        reconstruct(
            sfm_dir, scale_mm=scale_mm, photometric=photometric, texture_smoothing=smoothing
        )
        errors = _normal_errors(truth, load_capture(sfm_dir))
        errors["reconstruct_s"] = round(time.perf_counter() - started, 1)
        row[f"{name}_normals"] = errors
        print(f"{name} normals: {errors}")
    true_sigma, true_f = truth.truth["sigma"], np.asarray(truth.truth["F_tilde"])
    for name, normals, depth, poses in HYBRIDS:
        root = _hybrid(out / ("fit_" + name.replace(" ", "_")), sources, normals, depth, poses)
        fit = fit_capture(load_capture(root)).to_json()
        sigma = 100 * (fit["sigma"] / true_sigma - 1)
        f_tilde = 100 * (np.asarray(fit["F_tilde"]) / true_f - 1)
        print(
            f"{name:32s} sigma {sigma:+6.1f}%  F_tilde {np.round(f_tilde, 1).tolist()}%  "
            f"RMSE {fit['rgb_rmse']:.2f} levels"
        )
        row[name] = {"sigma_pct": round(sigma, 2), "F_tilde_pct": np.round(f_tilde, 2).tolist()}
    emit(row)


if __name__ == "__main__":
    main()
