"""A stereo laparoscope's right camera as held-out views of the left camera's surface points
(NumPy, I/O side).

The right image is taken at the same instant as the left one (no tissue motion between
them), from a viewpoint a baseline away, while the light stays beside the left lens. So a
right view changes the view direction V and keeps the light direction L: the left camera's
own frames never do that (its light moves with it), and a model that has the lobe's V
dependence wrong, or has absorbed it into something else, predicts the right views worse
than the left ones.

A tracked surface point (`ctjax._tracks.Tracks`, followed in the left frames by depth and
poses) is looked for in the right view of each frame: its left camera-frame point goes into
the right camera by the rig (`X_right = R X_left + T`, mm), is projected with the right
camera (undistorted) and the right image sampled bilinearly there. The observation stays
in the left camera's frame of that instant, where the light is (at the left lens or its
offset from it), with the right camera's centre `-R^T T` as the viewer (`shade`'s `eye`):
one model serves both cameras. The model is evaluated at the point itself (one corner;
the point's normal from its anchor frame), not at four pixel centres of the right view:
the right camera has no depth of its own.

An observation counts when it lands inside the right image, faces the right camera, is not
hidden (its depth agrees within the tracks' tolerance with the nearest of the left frame's
surface points splatted into the right view: a z-buffer), and none of the right image's
four neighbours is clipped in a channel (no channel of it counts then) or excluded
(`excluded/right/NAME.png`: an instrument).

The right camera is taken as the left one's twin behind the sensor: a right view carries
its frame's index (the exposure of that instant, as the left image's) and, for the
effects that read a pixel (vignetting about the principal point), its position relative
to the right camera's optical axis written as the left camera's pixel.
"""

import cv2
import numpy as np

from ._camera import Camera
from ._errors import CtjaxError
from ._point_normals import point_normals
from ._tracks import (
    DEFAULT_TOLERANCE,
    Tracks,
    observation_weight,
    sample_image,
    world_points,
)
from ._units import METRIC
from .io._encoding import SRGB, srgb_to_linear
from .io._excluded import excluded_pixels


def require_stereo(capture) -> None:
    """Raise a `CtjaxError` unless `capture` is a stereo capture with depth in mm."""
    if getattr(capture, "stereo", None) is None:
        raise CtjaxError(
            f'{capture.root}: no right camera (camera.json has no "stereo" block); right '
            "views need a stereo capture"
        )
    if capture.length_unit != METRIC:
        raise CtjaxError(
            f"{capture.root}: depth is in {capture.length_unit}, the stereo rig's T in mm; "
            "reconstruct the stereo capture first (`ctjax reconstruct`: depth in mm)"
        )


def right_image(capture, name: str) -> np.ndarray:
    """Frame `name`'s right image, linear and undistorted onto the right camera's own K
    (as the left frames are read), float32 (H, W, 3)."""
    recorded = capture.right_image(name)
    if recorded is None:
        raise CtjaxError(f"{capture.root}: frame {name} has no right image")
    linear = srgb_to_linear(recorded) if capture.encoding == SRGB else recorded
    linear = np.asarray(linear, np.float32)
    camera = capture.stereo.right
    if camera.distortion is not None:
        k = np.asarray(camera.intrinsic_matrix, np.float64)
        dist = np.asarray(camera.distortion, np.float64)
        linear = cv2.undistort(linear, k, dist, None, k)
    return linear


def right_excluded(capture, name: str) -> np.ndarray | None:
    """Frame `name`'s right image's excluded pixels (`excluded/right/NAME.png`: an
    instrument), undistorted as `right_image` is, None where the capture gives none."""
    camera = capture.stereo.right
    mask = excluded_pixels(capture.root, name, (camera.height, camera.width), right=True)
    if mask is None or camera.distortion is None:
        return mask
    k = np.asarray(camera.intrinsic_matrix, np.float64)
    dist = np.asarray(camera.distortion, np.float64)
    size = (camera.width, camera.height)
    maps = cv2.initUndistortRectifyMap(k, dist, None, k, size, cv2.CV_32FC1)
    return cv2.remap(mask.astype(np.uint8), *maps, cv2.INTER_NEAREST) > 0


def _project(camera: Camera, point: np.ndarray):
    z = point[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = float(camera.fx) * point[:, 0] / z + float(camera.cx)
        v = float(camera.fy) * point[:, 1] / z + float(camera.cy)
    inside = (z > 0) & (u >= 0) & (v >= 0) & (u <= camera.width - 1) & (v <= camera.height - 1)
    return np.where(inside, u, -10.0), np.where(inside, v, -10.0), inside


def z_buffer(capture, index: int) -> np.ndarray:
    """The right camera's depth (H, W; NaN where nothing lands) of frame `index`'s left
    surface: every left pixel with geometry moved into the right camera and splatted onto
    the four pixel centres around its projection, the nearest kept."""
    frame, camera, rig = capture.frames[index], capture.camera, capture.stereo
    right = rig.right
    rows, cols = np.nonzero(frame.geometry_mask)
    z = frame.depth[rows, cols].astype(np.float64)
    left = np.stack(
        [
            z * (cols - float(camera.cx)) / float(camera.fx),
            z * (rows - float(camera.cy)) / float(camera.fy),
            z,
        ],
        -1,
    )
    point = left @ rig.R.T + rig.T
    u, v, inside = _project(right, point)
    depth = np.full(right.height * right.width, np.inf)
    u0, v0, zr = np.floor(u[inside]).astype(int), np.floor(v[inside]).astype(int), point[inside, 2]
    for du in (0, 1):
        for dv in (0, 1):
            uu, vv = np.minimum(u0 + du, right.width - 1), np.minimum(v0 + dv, right.height - 1)
            np.minimum.at(depth, vv * right.width + uu, zr)
    depth[~np.isfinite(depth)] = np.nan
    return depth.reshape(right.height, right.width)


def _anchors(capture, tracks: Tracks):
    """The tracks' world points (P, 3), from their anchor pixels, and unit normals (P, 3):
    each point's one normal over its left views (`point_normals`; its anchor pixel's where
    none counts)."""
    camera = capture.camera
    world = np.empty((len(tracks), 3))
    normal = np.empty((len(tracks), 3))
    for index in np.unique(tracks.anchor_frame):
        frame = capture.frames[index]
        at = tracks.anchor_frame == index
        rows, cols = tracks.anchor_row[at], tracks.anchor_col[at]
        world[at] = world_points(camera, frame, rows, cols)
        normal[at] = frame.normals[rows, cols].astype(np.float64) @ frame.pose[:3, :3].T
    one = point_normals(tracks, capture)
    return world, np.where(np.all(np.isfinite(one), axis=-1, keepdims=True), one, normal)


def _right_observations(capture, index, world, normal, tolerance, saturation_level):
    """The points (world, normals: (P, 3)) seen in frame `index`'s right view: corners (P,
    4, ...) in the left camera frame of that instant, values, whether each counts, weights."""
    frame, rig = capture.frames[index], capture.stereo
    right = rig.right
    to_left = np.linalg.inv(frame.pose)
    point = world @ to_left[:3, :3].T + to_left[:3, 3]  # the left camera frame
    facing = normal @ to_left[:3, :3].T
    in_right = point @ rig.R.T + rig.T
    u, v, inside = _project(right, in_right)
    eye = rig.left_from_right()[:3, 3]
    with np.errstate(invalid="ignore"):
        depth = sample_image(z_buffer(capture, index), u, v, cv2.INTER_NEAREST)
        seen = inside & (np.abs(depth - in_right[:, 2]) <= tolerance * in_right[:, 2])
    seen &= np.sum(facing * (eye - point), axis=-1) > 0
    image = right_image(capture, frame.name)
    values = sample_image(image, u, v)
    spread = np.abs(values - sample_image(image, u, v, cv2.INTER_NEAREST))
    spread = np.max(spread, axis=-1)
    seen &= np.isfinite(spread)
    # A channel counts where none of the four neighbours is clipped in it.
    clipped = np.zeros(len(u), bool)
    for du in (0, 1):
        for dv in (0, 1):
            near = sample_image(image, np.floor(u) + du, np.floor(v) + dv, cv2.INTER_NEAREST)
            clipped |= np.any(~(near < saturation_level), axis=-1)
    seen &= ~clipped
    excluded = right_excluded(capture, frame.name)
    if excluded is not None:  # an instrument on any of the four neighbours
        for du in (0, 1):
            for dv in (0, 1):
                rows = np.clip(np.floor(v).astype(int) + dv, 0, right.height - 1)
                cols = np.clip(np.floor(u).astype(int) + du, 0, right.width - 1)
                seen &= ~excluded[rows, cols]
    values = np.where(seen[:, None], values, 0.0)
    weight = np.where(seen, observation_weight(np.where(seen, spread, 0.0)), 0.0)
    # Where it lies on the right sensor, as the left camera's pixel at the same place
    # relative to its optical axis: effects of the optics (vignetting about the principal
    # point) then act as the right camera's own, taken to be the left's twin.
    left = capture.camera
    u = float(left.cx) + (u - float(right.cx)) * float(left.fx) / float(right.fx)
    v = float(left.cy) + (v - float(right.cy)) * float(left.fy) / float(right.fy)
    pixel = np.stack([np.where(seen, u, 0.0), np.where(seen, v, 0.0)], -1)
    point = np.where(seen[:, None], point, (0.0, 0.0, 1.0))
    facing = np.where(seen[:, None], facing, (0.0, 0.0, -1.0))
    return point, facing, pixel, eye, values, seen, weight


def with_right_views(
    capture,
    tracks: Tracks,
    frames=None,
    *,
    tolerance: float = DEFAULT_TOLERANCE,
    saturation_level=None,
) -> tuple[Tracks, np.ndarray]:
    """`tracks` with one more view per frame of `frames` (default: every frame the tracks
    were followed in): that frame's right image. Returns the tracks and which of their
    observations are right views (P, M + len(frames), bool; observed ones only). A right
    value at or above `saturation_level` (one, or one per channel; default: the right
    camera's, `Capture.right_saturation`) is clipped."""
    require_stereo(capture)
    if saturation_level is None:
        saturation_level = np.asarray(capture.right_saturation, np.float32)
    if frames is None:
        frames = sorted({int(f) for f in np.unique(tracks.frame) if f >= 0})
    world, normal = _anchors(capture, tracks)
    p, m = tracks.observed.shape
    k = len(frames)
    extra = {
        "corner_point": np.zeros((p, k, 4, 3)),
        "corner_normal": np.zeros((p, k, 4, 3)),
        "corner_pixel": np.zeros((p, k, 4, 2)),
        "corner_weight": np.zeros((p, k, 4)),
        "values": np.zeros((p, k, 3)),
        "observed": np.zeros((p, k), bool),
        "weight": np.zeros((p, k)),
        "frame": np.full((p, k), -1),
        "corner_eye": np.zeros((p, k, 4, 3)),
    }
    for slot, index in enumerate(frames):
        point, facing, pixel, eye, values, seen, weight = _right_observations(
            capture, index, world, normal, tolerance, saturation_level
        )
        extra["corner_point"][:, slot] = point[:, None]
        extra["corner_normal"][:, slot] = facing[:, None]
        extra["corner_pixel"][:, slot] = pixel[:, None]
        extra["corner_weight"][:, slot, 0] = 1.0
        extra["values"][:, slot] = values
        extra["observed"][:, slot] = seen
        extra["weight"][:, slot] = weight
        extra["frame"][:, slot] = np.where(seen, index, -1)
        extra["corner_eye"][:, slot] = np.where(seen[:, None], eye, 0.0)[:, None]
    own_eye = np.zeros((p, m, 4, 3)) if tracks.corner_eye is None else tracks.corner_eye
    joined = {}
    for name, added in extra.items():
        mine = own_eye if name == "corner_eye" else getattr(tracks, name)
        joined[name] = np.concatenate([mine.astype(added.dtype), added], axis=1)
    right = np.zeros((p, m + k), bool)
    right[:, m:] = extra["observed"]
    anchors = {n: getattr(tracks, n) for n in ("anchor_frame", "anchor_row", "anchor_col")}
    return Tracks(**joined, **anchors), right
