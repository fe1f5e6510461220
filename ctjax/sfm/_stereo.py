"""Dense depth from a stereo laparoscope's pairs: rectified, matched by semi-global block
matching (OpenCV's StereoSGBM), back in the left camera's frame and pixel grid.

A stereo pair measures depth in millimetres at one instant: no size to give, no tissue
motion between the two views. What it is used for in `reconstruct`: SfM's scale (its poses
and points are up to scale; the pairs fix it), and dense points for each view's surface
where SfM has no features (the highlights, smooth wet tissue). SGBM's depth is noisy
(a fraction of a pixel of disparity is millimetres at a laparoscope's distance) and wrong
on highlights (they move between the two views): the surface spline smooths it and its
robust weights drop outliers. A learned stereo matcher (RAFT-Stereo and the like, trained
on da Vinci pairs) would give denser and smoother disparities; SGBM needs nothing beyond
OpenCV.
"""

import dataclasses

import cv2
import numpy as np

from .._errors import CaptureError, ReconstructionError
from ..io import Capture
from ..io._encoding import encode

# Matching on pixels no finer than this many (the points' density for the surface fit,
# which smooths over a knot spacing anyway).
DEFAULT_STRIDE = 4


@dataclasses.dataclass(frozen=True)
class StereoPoints:
    """Points measured by one stereo pair, in the left camera's frame (mm): where they are
    seen in the left image (u, v; the capture's undistorted grid) and their depth z."""

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    matched: float  # the share of the rectified left image's pixels SGBM matched

    def __len__(self) -> int:
        return len(self.z)


def _gray(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.clip(image * 255 + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)


def _matcher(disparities: int, block: int = 5):
    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=disparities,
        blockSize=block,
        P1=8 * block * block,
        P2=32 * block * block,
        disp12MaxDiff=1,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )


def stereo_points(
    capture: Capture, index: int, *, stride: int = DEFAULT_STRIDE, max_disparity: int | None = None
) -> StereoPoints:
    """The 3D points frame `index`'s stereo pair measures, every `stride`-th rectified pixel.

    The left image is the capture's (undistorted on load, so its camera has no distortion),
    the right one as recorded with the right camera's distortion; both are rectified
    (`cv2.stereoRectify`), matched (StereoSGBM, `max_disparity` pixels at most: by default
    a quarter of the width), each matched pixel triangulated and rotated back into the left
    camera's frame.
    """
    rig = capture.stereo
    if rig is None:
        raise CaptureError(f"{capture.root}: not a stereo capture (camera.json has no stereo)")
    frame = capture.frames[index]
    right = capture.right_image(frame.name)  # its size checked against the rig's
    left_camera = capture.camera
    size = (left_camera.width, left_camera.height)
    k1 = np.asarray(left_camera.intrinsic_matrix, np.float64)
    k2 = np.asarray(rig.right.intrinsic_matrix, np.float64)
    d2 = np.zeros(5) if rig.right.distortion is None else np.asarray(rig.right.distortion)
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(
        k1,
        np.zeros(5),
        k2,
        d2,
        size,
        rig.R,
        rig.T.reshape(3, 1),
        alpha=0,
        flags=cv2.CALIB_ZERO_DISPARITY,
    )
    maps = [
        cv2.initUndistortRectifyMap(k, d, r, p, size, cv2.CV_32FC1)
        for k, d, r, p in ((k1, np.zeros(5), r1, p1), (k2, d2, r2, p2))
    ]
    images = (encode(frame.image, capture.encoding), right)
    left_r, right_r = (
        cv2.remap(_gray(image), *m, cv2.INTER_LINEAR) for image, m in zip(images, maps, strict=True)
    )
    if max_disparity is None:
        max_disparity = left_camera.width // 4
    disparities = max(16, 16 * -(-int(max_disparity) // 16))
    disparity = _matcher(disparities).compute(left_r, right_r).astype(np.float32) / 16
    # The rectified left camera's view of the left image's field of view, not the border
    # the remap filled.
    inside = cv2.remap(np.ones(size[::-1], np.uint8), *maps[0], cv2.INTER_NEAREST) > 0
    matched = (disparity > 0.5) & inside
    points = cv2.reprojectImageTo3D(disparity, q)  # rectified left frame, mm
    rows, cols = np.mgrid[0 : size[1] : stride, 0 : size[0] : stride]
    keep = matched[rows, cols]
    rectified = points[rows[keep], cols[keep]].astype(np.float64)
    left = rectified @ r1  # R1 rotates the left frame into the rectified one: X = R1^T X_r
    ahead = np.isfinite(left).all(axis=1) & (left[:, 2] > 0)
    left = left[ahead]
    u = k1[0, 0] * left[:, 0] / left[:, 2] + k1[0, 2]
    v = k1[1, 1] * left[:, 1] / left[:, 2] + k1[1, 2]
    seen = (u > -0.5) & (u < size[0] - 0.5) & (v > -0.5) & (v < size[1] - 0.5)
    # Of the scene only: not the border, overlays or the pixels excluded (an instrument).
    rows = np.clip(np.round(v).astype(int), 0, size[1] - 1)
    seen &= frame.visible[rows, np.clip(np.round(u).astype(int), 0, size[0] - 1)]
    return StereoPoints(u[seen], v[seen], left[seen, 2], float(matched[inside].mean()))


def stereo_scale(surfaces, hulls, pairs, scale_info, rig) -> float:
    """SfM's scale from the stereo pairs: per frame the median ratio of the pair's depth to
    SfM's surface at the same pixels (inside its hull), then the median over frames; the
    frames' spread says how well the two agree."""
    ratios = {}
    for name, pair in pairs.items():
        surface, hull = surfaces[name], hulls[name]
        rows = np.clip(np.round(pair.v).astype(int), 0, hull.shape[0] - 1)
        cols = np.clip(np.round(pair.u).astype(int), 0, hull.shape[1] - 1)
        inside = hull[rows, cols]
        if inside.sum() < 16:
            continue
        sfm = surface.depth_and_gradient(pair.u[inside], pair.v[inside])[0]
        ratio = pair.z[inside] / sfm
        ratios[name] = float(np.median(ratio[np.isfinite(ratio) & (ratio > 0)]))
    if not ratios:
        raise ReconstructionError(
            "stereo: no pair matched SfM's surface (too few stereo points inside the frames' "
            "hulls); check camera.json's stereo block (R, T in mm, X_right = R X_left + T)"
        )
    scale = float(np.median(list(ratios.values())))
    spread = [abs(r / scale - 1) for r in ratios.values()]
    scale_info.update(
        metric=True,
        method="stereo",
        value=rig.baseline_mm,
        stereo_scale_per_frame=ratios,
        stereo_scale_max_deviation=float(max(spread)),
    )
    return scale


def stereo_report(pairs, rig, use: str) -> dict:
    """`ctjax reconstruct`'s report on the pairs: how many points each gave, and their use."""
    return {
        "baseline_mm": rig.baseline_mm,
        "matcher": "OpenCV StereoSGBM on the rectified pairs (cv2.stereoRectify)",
        "points_per_frame": {name: len(pair) for name, pair in pairs.items()},
        "matched_per_frame": {name: pair.matched for name, pair in pairs.items()},
        "surface": "each view's surface fitted to SfM's points and its pair's together (mm)"
        if use == "surface"
        else "SfM's points alone (the pairs give the scale)",
    }
