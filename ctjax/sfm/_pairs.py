"""A stereo capture reconstructed from its pairs alone (`ctjax reconstruct --stereo pairs`).

A scope held nearly still, as it often is in surgery, gives structure-from-motion no pair
of frames with parallax (a da Vinci clip of the SurgT challenge: "no initial image pair").
Its stereo pairs still measure metric depth at every instant. Here each frame's surface is
its own pair's points (`_stereo.stereo_points`) under the same smoothing B-spline as SfM's
(`fit_depth_surface`), the covered pixels those within two knots of a matched point, and
each frame's pose comes from the previous registered frame's by PnP (SIFT matches between
the left images, the previous frame's surface depth at its keypoints, RANSAC; world = the
first frame's camera). Measured on that clip (10 frames, 640 px): 1250-1680 inliers a
frame, reprojection 0.1-0.3 px, the camera 1.05 mm from the first frame at the last.
"""

import cv2
import numpy as np

from .._errors import CaptureError
from ..io import Capture
from ..io._encoding import encode
from ._stereo import stereo_points, stereo_report
from ._surface import fit_depth_surface

# A frame registers with at least this many PnP inliers.
MIN_INLIERS = 30
# PnP's RANSAC threshold (px) and the share of SIFT's second-best match distance kept.
REPROJECTION_PX = 1.5
RATIO = 0.75


def _gray(capture: Capture, index: int) -> np.ndarray:
    encoded = encode(capture.frames[index].image, capture.encoding)
    return cv2.cvtColor(np.clip(encoded * 255 + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)


def _relative_pose(capture, previous: int, index: int, depth: np.ndarray, features):
    """Frame `index`'s camera from frame `previous`'s (4x4, previous -> index) by PnP, its
    inliers and median reprojection error (px); None where it does not register."""
    camera = capture.camera
    (k0, d0), (k1, d1) = features(previous), features(index)
    if d0 is None or d1 is None or len(k0) < MIN_INLIERS or len(k1) < MIN_INLIERS:
        return None
    pairs = cv2.BFMatcher().knnMatch(d0, d1, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < RATIO * m[1].distance]
    if len(good) < MIN_INLIERS:
        return None
    p0 = np.array([k0[m.queryIdx].pt for m in good])
    p1 = np.array([k1[m.trainIdx].pt for m in good])
    rows = np.clip(np.round(p0[:, 1]).astype(int), 0, camera.height - 1)
    cols = np.clip(np.round(p0[:, 0]).astype(int), 0, camera.width - 1)
    z = depth[rows, cols]
    ok = np.isfinite(z)
    if ok.sum() < MIN_INLIERS:
        return None
    x = (p0[ok, 0] - float(camera.cx)) / float(camera.fx) * z[ok]
    y = (p0[ok, 1] - float(camera.cy)) / float(camera.fy) * z[ok]
    points = np.stack([x, y, z[ok]], -1)
    k = np.asarray(camera.intrinsic_matrix, np.float64)
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        points, p1[ok], k, None, reprojectionError=REPROJECTION_PX, iterationsCount=2000
    )
    if not found or inliers is None or len(inliers) < MIN_INLIERS:
        return None
    projected, _ = cv2.projectPoints(points[inliers.ravel()], rvec, tvec, k, None)
    error = np.linalg.norm(projected[:, 0] - p1[ok][inliers.ravel()], axis=1)
    moved = np.eye(4)
    moved[:3, :3], moved[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    return moved, len(inliers), float(np.median(error))


def pairs_reconstruction(capture: Capture, knot_spacing_px: float, say):
    """A stereo capture from its pairs alone (see the module doc), depth in mm: per
    registered frame its surface (`DepthSurface`), covered pixels, pose (camera-to-world)
    and number of points, as {name: (surface, hull, pose, points)}; and the report."""
    if capture.stereo is None:
        raise CaptureError(
            f"{capture.root}: --stereo pairs needs a stereo capture (camera.json's stereo)"
        )
    camera = capture.camera
    bounds = (0.0, camera.width - 1.0, 0.0, camera.height - 1.0)
    kernel = np.ones((int(4 * knot_spacing_px) + 1,) * 2, np.uint8)
    sift = cv2.SIFT_create(4000)
    cache = {}

    def features(index):
        if index not in cache:
            cache[index] = sift.detectAndCompute(_gray(capture, index), None)
        return cache[index]

    surfaces, hulls, pairs, depths = {}, {}, {}, {}
    for index, frame in enumerate(capture.frames):
        say(f"frame {frame.name}: depth from its stereo pair")
        points = stereo_points(capture, index)
        if len(points) < 100:
            raise CaptureError(
                f"{capture.root}: the pair of {frame.name} matched {len(points)} points "
                "(under 100): check camera.json's stereo block and the right image"
            )
        pairs[frame.name] = points
        surfaces[frame.name] = fit_depth_surface(
            points.u, points.v, points.z, bounds, knot_spacing_px=knot_spacing_px
        )
        near = np.zeros((camera.height, camera.width), np.uint8)
        rows = np.clip(np.round(points.v).astype(int), 0, camera.height - 1)
        cols = np.clip(np.round(points.u).astype(int), 0, camera.width - 1)
        near[rows, cols] = 1
        hulls[frame.name] = cv2.dilate(near, kernel) > 0
        v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
        depth, _ = surfaces[frame.name].geometry(camera, u, v)
        depths[index] = np.where(hulls[frame.name], depth, np.nan)
    poses, pnp, last = {capture.frames[0].name: np.eye(4)}, {}, 0
    for index in range(1, len(capture)):
        name = capture.frames[index].name
        found = _relative_pose(capture, last, index, depths[last], features)
        if found is None:
            pnp[name] = None
            continue
        moved, inliers, error = found
        previous = poses[capture.frames[last].name]
        poses[name] = previous @ np.linalg.inv(moved)
        pnp[name] = {"against": capture.frames[last].name, "inliers": inliers, "px": error}
        say(f"frame {name}: {inliers} PnP inliers, reprojection {error:.2f} px")
        last = index
    views = {
        name: (surfaces[name], hulls[name], pose, len(pairs[name])) for name, pose in poses.items()
    }
    names = [f.name for f in capture.frames]
    unregistered = [n for n in names if n not in views]
    errors = [p["px"] for p in pnp.values() if p is not None]
    report = {
        "method": "stereo pairs: each frame's depth from its own pair, poses by PnP",
        "frames": len(names),
        "registered": [n for n in names if n in views],
        "unregistered": unregistered,
        "reference_frame": names[0],
        "points": int(sum(len(p) for p in pairs.values())),
        "mean_reprojection_error_px": float(np.mean(errors)) if errors else 0.0,
        "coverage": float(np.mean([hulls[n].mean() for n in views])),
        "coverage_per_frame": {n: float(hulls[n].mean()) for n in views},
        "pnp": pnp,
        "scale": {"method": "stereo", "metric": True, "baseline_mm": capture.stereo.baseline_mm},
        "length_unit": "mm",
        "surface": {
            "model": "each frame's penalised cubic B-spline depth map fitted to its own "
            "pair's points (StereoSGBM), normals from its derivatives",
            "knot_spacing_px": float(knot_spacing_px),
            "points_per_frame": {n: len(p) for n, p in pairs.items()},
            "residual_rms_per_frame": {n: surfaces[n].residual_rms for n in views},
            "photometric": {"refined": False, "reason": "not with --stereo pairs"},
        },
        "stereo": stereo_report(pairs, capture.stereo, "pairs")
        | {"surface": "each frame's surface fitted to its own pair's points alone (mm)"},
        "world_frame": f"camera frame of {names[0]} (its pose is the identity)",
        "focal": {"status": "fixed"},
        "warnings": [
            f"frame {n} did not register by PnP against the previous registered frame "
            "(skipped; no depth or normals for it)"
            for n in unregistered
        ],
    }
    return views, report
