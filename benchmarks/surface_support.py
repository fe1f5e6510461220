"""How far the highlights lie from the structure-from-motion points their surface was fitted
to: is S on reconstructed surface, or on surface the depth spline extrapolated?

    python benchmarks/surface_support.py CAPTURE [...] [--knots K]

Runs `ctjax reconstruct`'s structure from motion and surfaces on each capture's images, in
memory (`ctjax.sfm.reconstruct_capture`, SfM's points alone: no texture refinement), keeps
each frame's inlier points' projections (the points its depth spline was fitted to), and
measures every pixel's distance to the nearest of them. Per capture: the share of the
surface (the hull of the points, where the frame has depth) and of S (`ctjax masks`'
default rule) farther than one and two knot spacings (the spline's own scale: a surface
there is the spline's continuation, not a measurement), and S's median distance against
the surface's. A pale wall close to the scope carries no features; where S is mostly there,
the highlights' normals are the spline's guess.

Measured (2026-12-05; the captures of `benchmarks/real_video.py`, 640 px, and SCARED 31-54
from `benchmarks/scared_capture.py`; knot spacing 32 px): the shared sinus (12 frames):
S 34.8% beyond one knot spacing from every point against 3.1% of the surface (medians 8.9
and 7.6 px; 21 s); SCARED 31-54 (24 frames): none either way (3.6 and 2.2 px; 224 s); the
cholecystectomy (12 frames): S 0.1%, the surface 0.6% (7.8 and 5.0 px; 49 s). The sinus
at full resolution (35 frames at 1920x1080, knot spacing 96 px): S 27.6% against 1.4%,
medians 69.6 and 12.1 px (605 s, 4.7 GB).
"""

import argparse
import dataclasses
from pathlib import Path

import cv2
import numpy as np
from _results import emit

from ctjax.io import load_capture
from ctjax.sfm import _reconstruct
from ctjax.specular import capture_sets


def _supports(capture, knots):
    """Each registered frame's inlier points' projections (u, v), by frame name."""
    kept = {}
    view_surfaces = _reconstruct._view_surfaces

    def recording(camera, sparse, points, world_from_ref, unit, knot_spacing_px, say):
        out = view_surfaces(camera, sparse, points, world_from_ref, unit, knot_spacing_px, say)
        surfaces, *_ = out
        for name, surface in surfaces.items():
            u, v, *_ = surface.points
            kept[name] = (np.asarray(u)[surface.inliers], np.asarray(v)[surface.inliers])
        return out

    _reconstruct._view_surfaces = recording
    try:
        reconstruction = _reconstruct.reconstruct_capture(
            capture, photometric=False, knot_spacing_px=knots
        )
    finally:
        _reconstruct._view_surfaces = view_surfaces
    return reconstruction, kept


def measure(root: Path, knots: float | None) -> dict:
    capture = load_capture(root)
    reconstruction, supports = _supports(capture, knots)
    spacing = knots or max(capture.camera.width, capture.camera.height) / 20
    frames = []
    for frame in capture.frames:
        view = reconstruction.views.get(frame.name)
        if view is not None:
            depth, normals = view.depth_and_normals(capture.camera)
            frames.append(dataclasses.replace(frame, depth=depth, normals=normals, pose=view.pose))
    capture = dataclasses.replace(capture, frames=tuple(frames))
    sets = capture_sets(capture)
    surface_d, s_d = [], []
    for frame, s in zip(capture.frames, sets, strict=True):
        if frame.name not in supports or frame.depth is None:
            continue
        u, v = supports[frame.name]
        seeds = np.ones(frame.geometry_mask.shape, np.uint8)
        cols, rows = np.rint(u).astype(int), np.rint(v).astype(int)
        inside = (rows >= 0) & (rows < seeds.shape[0]) & (cols >= 0) & (cols < seeds.shape[1])
        seeds[rows[inside], cols[inside]] = 0
        distance = cv2.distanceTransform(seeds, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        surface = frame.geometry_mask
        surface_d.append(distance[surface])
        s_d.append(distance[surface & s.specular])
    surface_d, s_d = np.concatenate(surface_d), np.concatenate(s_d)
    far = lambda d, k: float(np.mean(d > k * spacing)) if d.size else float("nan")  # noqa: E731
    return {
        "capture": str(root),
        "frames": len(capture.frames),
        "knot_spacing_px": spacing,
        "surface_pixels": int(surface_d.size),
        "s_pixels_on_surface": int(s_d.size),
        "surface_beyond_1_knot": far(surface_d, 1),
        "surface_beyond_2_knots": far(surface_d, 2),
        "s_beyond_1_knot": far(s_d, 1),
        "s_beyond_2_knots": far(s_d, 2),
        "surface_median_px": float(np.median(surface_d)) if surface_d.size else None,
        "s_median_px": float(np.median(s_d)) if s_d.size else None,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("captures", nargs="+", type=Path, help="capture folders (images/)")
    parser.add_argument("--knots", type=float, default=None, help="knot spacing, px")
    args = parser.parse_args()
    for root in args.captures:
        row = measure(root, args.knots)
        print(
            f"{root}: {row['frames']} frames; beyond 1 / 2 knot spacings "
            f"({row['knot_spacing_px']:.0f} px): surface {row['surface_beyond_1_knot']:.1%} / "
            f"{row['surface_beyond_2_knots']:.1%}, S {row['s_beyond_1_knot']:.1%} / "
            f"{row['s_beyond_2_knots']:.1%}; median distance surface {row['surface_median_px']:.1f}"
            f" px, S {row['s_median_px']:.1f} px ({row['s_pixels_on_surface']} S pixels)"
        )
        emit(row)


if __name__ == "__main__":
    main()
