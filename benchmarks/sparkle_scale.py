"""The sparkle density's sigma against the scale of the normals, on a stereo capture.

    python benchmarks/sparkle_scale.py CAPTURE [--width 640] [--knots 32 24 16 12 8] [--work DIR]

CAPTURE is a stereo capture (right/NAME.png and camera.json's stereo block, e.g. the SurgT
clip `benchmarks/surgt_capture.py` builds), scaled to `--width` pixels wide (as
`benchmarks/real_video.py` prepares it). For each knot spacing, `reconstruct --stereo
pairs` gives every frame its own surface (its own pair's StereoSGBM points under a
smoothing spline with that spacing: the finest relief its normals resolve), and this
prints:

- the normals' scatter: the same world point's normal from two frames' independent
  surfaces (frame i's pixel moved by the poses into frame j, kept where j's depth agrees
  within 2%), in S and elsewhere. Independent Gaussian tilts of RMS e (tan) in each
  surface make the angle between two of them Rayleigh with median 1.1774 e, so
  e = tan(median) / 1.1774 (the median, not the RMS: a few wild normals would dominate
  a mean of tangents); a bias both surfaces share (relief both smooth away) is not seen;
- the sparkle density (`ctjax.specular.sparkle_density`: where S lies over theta_h, the
  angle between the normal and H) with and without that error removed, and its even and
  odd frames apart.

A sigma that falls as the knots get finer is relief the coarse normals did not resolve
(sparkles on folds smaller than a knot); one that rises again is the finer normals' noise,
heavier-tailed than the median's e says.
"""

import argparse
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import emit
from real_video import prepare

from ctjax.io import load_capture
from ctjax.sfm import reconstruct
from ctjax.specular import capture_sets, sparkle_density

# Rayleigh: the median of |a - b| for independent 2-D Gaussian tilts of RMS e each.
_RAYLEIGH_MEDIAN = math.sqrt(2 * math.log(2))


def _world(frame, rays):
    rotation, translation = frame.pose[:3, :3], frame.pose[:3, 3]
    return (rays * frame.depth[..., None]) @ rotation.T + translation, frame.normals @ rotation.T


def normal_scatter(capture, sets) -> dict:
    """Angles (degrees) between each frame's normals and another frame's at the same world
    point, in S and outside it, and the per-surface error e (tan) they imply."""
    camera = capture.camera
    height, width = capture.frames[0].depth.shape
    v, u = np.mgrid[0:height, 0:width]
    rays = np.stack(
        [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones((height, width))], -1
    )
    angles = {"S": [], "elsewhere": []}
    for i, frame in enumerate(capture.frames):
        points, normals = _world(frame, rays)
        inside = frame.geometry_mask
        for j, other in enumerate(capture.frames):
            if j == i:
                continue
            rotation, translation = other.pose[:3, :3], other.pose[:3, 3]
            local = (points - translation) @ rotation
            with np.errstate(invalid="ignore", divide="ignore"):
                uj = camera.fx * local[..., 0] / local[..., 2] + camera.cx
                vj = camera.fy * local[..., 1] / local[..., 2] + camera.cy
            ok = inside & np.isfinite(uj) & np.isfinite(vj)
            uj = np.clip(np.where(ok, np.round(uj), 0), 0, width - 1).astype(int)
            vj = np.clip(np.where(ok, np.round(vj), 0), 0, height - 1).astype(int)
            depth_j = other.depth[vj, uj]
            with np.errstate(invalid="ignore"):
                ok &= other.geometry_mask[vj, uj] & (
                    np.abs(depth_j - local[..., 2]) < 0.02 * local[..., 2]
                )
            cosine = np.clip(np.sum(normals * (other.normals[vj, uj] @ rotation.T), -1), -1, 1)
            angle = np.degrees(np.arccos(cosine))
            angles["S"].append(angle[ok & sets[i].specular])
            angles["elsewhere"].append(angle[ok & ~sets[i].specular])
    out = {}
    for name, parts in angles.items():
        a = np.concatenate(parts)
        median = float(np.median(a)) if a.size else float("nan")
        e = math.tan(math.radians(median)) / _RAYLEIGH_MEDIAN
        out[name] = {
            "pairs": int(a.size),
            "median_deg": median,
            "p90_deg": float(np.percentile(a, 90)) if a.size else float("nan"),
            "e_tan": e,
            "e_deg": math.degrees(math.atan(e)),
        }
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("capture", type=Path, help="a stereo capture (right/, stereo block)")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--knots", type=float, nargs="+", default=[32.0, 24.0, 16.0, 12.0, 8.0])
    parser.add_argument("--work", type=Path, default=Path("sparkle-scale"))
    args = parser.parse_args(argv)
    scaled = prepare(args.capture, args.work, args.frames, args.width)
    for knot in args.knots:
        folder = args.work / f"knots-{knot:g}px"
        started = time.perf_counter()
        if not (folder / "poses.json").exists():
            shutil.rmtree(folder, ignore_errors=True)
            reconstruct(scaled, folder, stereo="pairs", knot_spacing_px=knot)
        capture = load_capture(folder)
        sets = capture_sets(capture)
        scatter = normal_scatter(capture, sets)
        raw = sparkle_density(capture, sets=sets).to_json()
        e_deg = scatter["S"]["e_deg"]
        corrected = sparkle_density(capture, sets=sets, normal_error_deg=e_deg).to_json()
        print(
            f"knots {knot:g} px: normals' scatter between frames, median (p90) S "
            f"{scatter['S']['median_deg']:.1f} ({scatter['S']['p90_deg']:.1f}) deg, elsewhere "
            f"{scatter['elsewhere']['median_deg']:.1f} ({scatter['elsewhere']['p90_deg']:.1f}) "
            f"deg -> e {e_deg:.1f} deg in S\n"
            f"  sparkle density sigma {raw['sigma']:.3f} (even {raw['halves'][0]:.3f}, odd "
            f"{raw['halves'][1]:.3f}), theta_h median S {raw['theta_h_median_specular_deg']:.1f}"
            f" / all {raw['theta_h_median_deg']:.1f} deg; e removed: "
            f"{corrected['sigma_corrected']:.3f} ({corrected['status']})"
        )
        emit(
            {
                "capture": str(args.capture),
                "width": args.width,
                "knot_spacing_px": knot,
                "scatter": scatter,
                "sigma": raw["sigma"],
                "halves": raw["halves"],
                "theta_h_median_specular_deg": raw["theta_h_median_specular_deg"],
                "theta_h_median_deg": raw["theta_h_median_deg"],
                "sigma_corrected": corrected["sigma_corrected"],
                "status_corrected": corrected["status"],
                "seconds": round(time.perf_counter() - started, 1),
            }
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
