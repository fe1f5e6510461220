"""Right views of a stereo capture on real tissue, each frame alone.

    .venv/bin/python benchmarks/stereo_right_views.py CAPTURE [--width 640] [--frames 10]
        [--work DIR] [--fit-frame 0] [--knot-px 12]

Each frame's depth and normals come from its own pair (OpenCV's StereoSGBM points,
`ctjax.sfm._stereo.stereo_points`, under a smoothing B-spline, `fit_depth_surface`): no
structure-from-motion, which a scope that barely moves gives no parallax. Each frame is then
a capture of its own. The paper's BRDF is fitted on one frame's left and right views
(`fit_albedo_map(..., right_views=True)`: V moves between the two eyes, L does not), and
every frame's right view is predicted from its left view (each point's albedo from its left
view, `ctjax.heldout.RightViews`) by that fit and by the Lambertian model.

Under the paper's light (at the left lens) a Lambertian point's right and left values are
the same: L and its distance do not change between the two eyes, only V. So the Lambertian
model's right-view error is the view dependence the frames show, plus noise, registration
and depth errors; a lobe that is there lowers it, one that is not does not.

Then the frames are registered to the first by PnP (SIFT matches against the first frame's
pair depth) and the paper's BRDF is fitted across the first `--fitted` frames, with their
left views alone and with their right views too, and judged on the other frames' right views.

Prints, per frame, the number of right views judged and the right-view RMSE of each model
(8-bit levels; Lambertian's also by where the points are anchored: inside the highlight set
S, within 12 px of it, elsewhere), and the fit (sigma, F_tilde, status). Slow (a minute or
two): a benchmark.
"""

import argparse
import json
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
from _results import emit
from real_video import prepare

from ctjax import ShadingModel
from ctjax._right_views import with_right_views
from ctjax.estimation._map_fit import fit_albedo_map
from ctjax.fitting import TrackSamples
from ctjax.fitting._map_least_squares import heldout_map_rmse
from ctjax.heldout import RightViews
from ctjax.io import load_capture
from ctjax.lights import ColocatedLight
from ctjax.lobes import BRDF, Lambertian
from ctjax.observations import Observations
from ctjax.sfm._stereo import stereo_points
from ctjax.sfm._surface import fit_depth_surface


def frame_capture(capture, index: int, out: Path, knot_px: float) -> Path:
    """Frame `index` of a stereo capture as a one-frame capture with depth and normals
    from its own pair (mm), geometry within 2 knots of a matched point, identity pose."""
    frame, camera = capture.frames[index], capture.camera
    points = stereo_points(capture, index)
    bounds = (0.0, camera.width - 1.0, 0.0, camera.height - 1.0)
    surface = fit_depth_surface(points.u, points.v, points.z, bounds, knot_spacing_px=knot_px)
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(float)
    depth, normals = surface.geometry(camera, u, v)
    near = np.zeros((camera.height, camera.width), np.uint8)
    cols = np.clip(np.round(points.u).astype(int), 0, camera.width - 1)
    rows = np.clip(np.round(points.v).astype(int), 0, camera.height - 1)
    near[rows, cols] = 1
    kernel = np.ones((int(4 * knot_px) + 1,) * 2, np.uint8)
    covered = cv2.dilate(near, kernel) > 0
    depth[~covered] = np.nan
    normals[~covered] = np.nan
    if out.is_dir():
        shutil.rmtree(out)
    for folder in ("images", "right", "depth", "normals"):
        (out / folder).mkdir(parents=True)
    for folder in ("images", "right"):
        source = next((capture.root / folder).glob(f"{frame.name}.*"))
        shutil.copy(source, out / folder / source.name)
    np.save(out / "depth" / f"{frame.name}.npy", depth.astype(np.float32))
    np.save(out / "normals" / f"{frame.name}.npy", normals.astype(np.float32))
    (out / "poses.json").write_text(json.dumps({frame.name: np.eye(4).tolist()}))
    shutil.copy(capture.root / "camera.json", out / "camera.json")
    return out


def by_distance_to_s(capture, model) -> dict:
    """`model`'s right-view RMSE (levels) by where the points are anchored: inside S (its
    unclipped channels), within 12 px of it, elsewhere; with the number of views."""
    obs = Observations.of(capture)
    tracks = obs.tracks(frames=[0], max_points=12_000, seed=0)  # as `RightViews.of`
    joined, right = with_right_views(capture, tracks, [0])
    samples = TrackSamples.of(joined)
    distance = obs.specular_distance(0)[tracks.anchor_row, tracks.anchor_col]
    out = {}
    for part, where in (
        ("in_S", distance <= 0),
        ("near_S", (distance > 0) & (distance <= 12)),
        ("elsewhere", distance > 12),
    ):
        judged = np.zeros(samples.weight.shape, bool)
        judged[:, : len(joined)] = (right & where[:, None]).T
        out[part] = (heldout_map_rmse(model, samples, judged), int(judged.sum()))
    return out


def registered(frames: list, out: Path) -> Path:
    """The one-frame captures as one capture, each frame's pose from PnP against the first
    (SIFT matches, the first frame's pair depth at its keypoints, RANSAC): structure-from-
    motion has too little parallax here, and the pairs give the depth it would have given."""
    camera, names = frames[0].camera, [c.frames[0].name for c in frames]
    k = np.asarray(camera.intrinsic_matrix, np.float64)
    sift, matcher = cv2.SIFT_create(4000), cv2.BFMatcher()

    def features(capture):
        encoded = np.clip(capture.frames[0].image ** (1 / 2.2) * 255, 0, 255).astype(np.uint8)
        return sift.detectAndCompute(cv2.cvtColor(encoded, cv2.COLOR_RGB2GRAY), None)

    first, first_descriptors = features(frames[0])
    depth = frames[0].frames[0].depth
    poses = {names[0]: np.eye(4)}
    for name, capture in zip(names[1:], frames[1:], strict=True):
        keypoints, descriptors = features(capture)
        pairs = matcher.knnMatch(first_descriptors, descriptors, k=2)
        good = [m for m, second in pairs if m.distance < 0.75 * second.distance]
        p0 = np.array([first[m.queryIdx].pt for m in good])
        p1 = np.array([keypoints[m.trainIdx].pt for m in good])
        z = depth[np.round(p0[:, 1]).astype(int), np.round(p0[:, 0]).astype(int)]
        ok = np.isfinite(z)
        x = (p0[ok, 0] - float(camera.cx)) / float(camera.fx) * z[ok]
        y = (p0[ok, 1] - float(camera.cy)) / float(camera.fy) * z[ok]
        points = np.stack([x, y, z[ok]], -1)
        _, rvec, tvec, inliers = cv2.solvePnPRansac(
            points, p1[ok], k, None, reprojectionError=1.5, iterationsCount=2000
        )
        world_to_camera = np.eye(4)
        world_to_camera[:3, :3], world_to_camera[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
        poses[name] = np.linalg.inv(world_to_camera)
        moved = np.linalg.norm(poses[name][:3, 3])
        print(f"  {name}: {len(inliers)} of {int(ok.sum())} matches, camera moved {moved:.2f} mm")
    if out.is_dir():
        shutil.rmtree(out)
    for folder in ("images", "right", "depth", "normals"):
        (out / folder).mkdir(parents=True)
        for capture in frames:
            for path in (capture.root / folder).iterdir():
                shutil.copy(path, out / folder / path.name)
    shutil.copy(frames[0].root / "camera.json", out / "camera.json")
    (out / "poses.json").write_text(json.dumps({n: p.tolist() for n, p in poses.items()}))
    return out


def across_frames(frames: list, work: Path, fitted: int) -> dict:
    """The paper's BRDF fitted on the first `fitted` frames, registered (left views alone,
    then with the right views), and judged on the other frames' right views."""
    print("registering the frames (PnP on the first frame's pair depth):")
    names = [c.frames[0].name for c in frames]
    everything = load_capture(registered(frames, work / "registered"))
    first = load_capture(registered(frames[:fitted], work / "registered_fit"))
    lambertian = ShadingModel(BRDF(Lambertian(np.ones(3))), ColocatedLight())
    out = {}
    views = RightViews.of(everything, range(fitted, len(frames)))
    out["lambertian"] = views.rmse(lambertian)
    for right in (False, True):
        fit = fit_albedo_map(first, right_views=right)
        found = fit.to_json()
        key = "fit_with_right_views" if right else "fit_left_views"
        out[key] = {
            "sigma": found["sigma"],
            "F_tilde": found["F_tilde"],
            "status": found["status"],
            "halves": {k: v["sigma"] for k, v in found.get("halves", {}).items()},
            "judged": views.rmse(fit.model),
        }
    print(f"fitted on {names[:fitted]}, judged on the right views of {names[fitted:]}:")
    print(
        f"  Lambertian: right {out['lambertian']['right']:.2f}, left "
        f"{out['lambertian']['left']:.2f} levels ({out['lambertian']['views']} right views)"
    )
    for key in ("fit_left_views", "fit_with_right_views"):
        f = out[key]
        print(
            f"  {key}: sigma {f['sigma']:.4g} (halves {f['halves']}), F_tilde "
            f"{np.round(f['F_tilde'], 4).tolist()}, {f['status']}; right "
            f"{f['judged']['right']:.2f}, left {f['judged']['left']:.2f} levels"
        )
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--work", type=Path, default=Path("/tmp/ctjax-stereo-right-views"))
    parser.add_argument("--fit-frame", type=int, default=0)
    parser.add_argument("--knot-px", type=float, default=12.0)
    parser.add_argument(
        "--fitted", type=int, default=6, help="frames fitted on across frames (registered)"
    )
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    scaled = load_capture(prepare(args.capture, args.work, args.frames, args.width))
    started = time.perf_counter()
    frames = [
        load_capture(frame_capture(scaled, i, args.work / "frames" / f.name, args.knot_px))
        for i, f in enumerate(scaled.frames)
    ]
    print(f"depth from the pairs: {time.perf_counter() - started:.1f} s, {len(frames)} frames")
    fit = fit_albedo_map(frames[args.fit_frame], right_views=True)
    found = fit.to_json()
    print(
        f"fit on {scaled.frames[args.fit_frame].name} (left and right views): sigma "
        f"{found['sigma']:.4g}, F_tilde {np.round(found['F_tilde'], 4).tolist()}, status "
        f"{found['status']}, {found.get('n_right_views')} right views; RMSE "
        f"{found['rgb_rmse']:.2f} vs Lambertian {found['lambertian']['rgb_rmse']:.2f} levels"
    )
    lambertian = ShadingModel(BRDF(Lambertian(np.ones(3))), ColocatedLight())
    rows = []
    for capture in frames:
        views = RightViews.of(capture)
        judged = {"lambertian": views.rmse(lambertian), "fit": views.rmse(fit.model)}
        row = {"frame": capture.frames[0].name, "views": judged["fit"]["views"]}
        row |= {name: value["right"] for name, value in judged.items()}
        parts = by_distance_to_s(capture, lambertian)
        row["lambertian_by_anchor"] = parts
        rows.append(row)
        where = ", ".join(f"{k} {v:.2f} ({n})" for k, (v, n) in parts.items())
        print(
            f"{row['frame']}: {row['views']} right views, RMSE Lambertian "
            f"{row['lambertian']:.2f} ({where}), the fit {row['fit']:.2f} levels"
        )
    held = [r for i, r in enumerate(rows) if i != args.fit_frame]
    if held:
        lam, cook = (np.mean([r[k] for r in held]) for k in ("lambertian", "fit"))
        print(f"other frames, mean: Lambertian {lam:.2f}, the fit {cook:.2f} levels")
    across = across_frames(frames, args.work, args.fitted) if len(frames) > args.fitted else {}
    emit({"capture": str(args.capture), "fit": found, "frames": rows, "across_frames": across})


if __name__ == "__main__":
    main()
