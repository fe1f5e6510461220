"""Surface points followed across frames by depth and poses (NumPy, I/O side).

The light of a laparoscope moves with the camera, so one surface point is lit and seen under
different angles in different frames: inside the highlight in some, outside it in most. Its
albedo is one unknown for all of them, which is what makes a per-point albedo identifiable
from several frames (and not from one). A *track* is one surface point, anchored at a pixel
of one frame, with its observations in the frames that see it.

Correspondence: the anchor pixel's camera-frame point (from depth) goes to the world by the
anchor frame's pose and into every other frame by that frame's inverse pose; the value there
is the bilinear sample of that frame's image. An observation counts only when

- it lands inside the image, on four neighbours that all have depth and a normal (a missing
  neighbour is a silhouette or a masked highlight);
- for a channel, none of the four neighbours is clipped in it (a clipped value is not the
  model's): the BRDF fit keeps only observations with no clipped channel, the albedo maps
  use every channel that counts;
- the frame's own depth there agrees with the point's depth in that frame within
  `tolerance` (relative): otherwise the point is hidden (occlusion) or the geometry or pose
  is wrong there (SfM at silhouettes, estimated poses).

The anchor's own observation is its pixel, exactly. Elsewhere the model is evaluated at
the four pixel centres around the projection with that frame's own depth and normals, and
interpolated like the image (see `Tracks`).
"""

import dataclasses

import cv2
import numpy as np

from ._camera import Camera
from ._errors import CtjaxError
from ._geometry import points_from_depth

# Frames a point is looked for in besides its own: the nearest in camera position. Bounds
# memory and time on long videos; a short capture uses all of its frames.
DEFAULT_NEIGHBOURS = 12
# The image noise the observation weights assume: 1 8-bit level (linear units).
NOISE = 1 / 255
# Default relative depth agreement for a point to count as seen (1% of its depth: 0.7 mm at
# a 70 mm working distance, far above float32 depth and interpolation errors, far below the
# depth steps at silhouettes).
DEFAULT_TOLERANCE = 0.01


@dataclasses.dataclass(frozen=True)
class Tracks:
    """P surface points, each observed in up to M frames (padded; `observed` says which).

    An observation is the bilinear sample of a frame's image at the point's projection, so
    the model is evaluated the same way: at the four pixel centres around it (`corner_*`,
    with the frame's own depth and normals there) and combined with the bilinear weights
    `corner_weight`. The shading is then interpolated exactly as the image is; only the
    albedo is taken as the point's (see `observation_weight`). The anchor's own observation
    is its pixel (one corner of weight 1).

    Per observation (P, M, 4 corners): camera-frame points (mm), unit normals, pixels
    (u, v) and bilinear weights; per observation (P, M): the sampled linear RGB, whether it
    counts (`observed`), its least-squares weight (`weight`, 0 where not observed) and the
    frame's index (`frame`, -1 where not observed). Per point (P,): the anchor frame, row
    and column.
    """

    corner_point: np.ndarray  # (P, M, 4, 3)
    corner_normal: np.ndarray  # (P, M, 4, 3)
    corner_pixel: np.ndarray  # (P, M, 4, 2) (u, v)
    corner_weight: np.ndarray  # (P, M, 4)
    values: np.ndarray  # (P, M, 3)
    observed: np.ndarray  # (P, M) bool
    weight: np.ndarray  # (P, M)
    frame: np.ndarray  # (P, M) int
    anchor_frame: np.ndarray  # (P,)
    anchor_row: np.ndarray  # (P,)
    anchor_col: np.ndarray  # (P,)

    def __len__(self) -> int:
        return self.observed.shape[0]

    @property
    def views(self) -> np.ndarray:
        """(P,) number of frames each point is observed in."""
        return self.observed.sum(axis=1)

    def select(self, keep: np.ndarray) -> "Tracks":
        """The tracks at index or mask `keep`."""
        return Tracks(*(getattr(self, f.name)[keep] for f in dataclasses.fields(self)))


def observation_weight(spread: np.ndarray) -> np.ndarray:
    """Weight of an interpolated observation: NOISE^2 / (NOISE^2 + spread^2), where
    `spread` is how far the bilinear value is from the nearest pixel's (max over channels).

    A point-sampled texture finer than a pixel makes the bilinear value another point's
    albedo: measured on ctjax's synthetic tissue, it dominated the albedo error of averaging
    over frames (median 1.2% against 1.0% with these weights, true BRDF; the anchor's own,
    exact observation has weight 1)."""
    return NOISE**2 / (NOISE**2 + np.square(spread))


def require_poses(capture) -> None:
    """Raise a `CtjaxError` naming the frames without a pose or depth."""
    missing = [f.name for f in capture.frames if f.pose is None or f.depth is None]
    if missing:
        raise CtjaxError(
            f"{capture.root}: frame(s) {', '.join(missing[:5])} have no pose or no depth; "
            "an albedo map follows surface points across frames by depth and poses.json "
            "(or reconstruct the shape first: `ctjax reconstruct`), else use --albedo uniform"
        )


def partners(capture, index: int, count: int | None, among=None) -> list[int]:
    """The frames a point of frame `index` is looked for in: itself first, then the `count`
    others nearest in camera position (all of them when `count` is None), from the frames
    `among` (all by default)."""
    centre = capture.frames[index].pose[:3, 3]
    among = range(len(capture.frames)) if among is None else among
    others = [i for i in among if i != index]
    distance = [float(np.linalg.norm(capture.frames[i].pose[:3, 3] - centre)) for i in others]
    order = [others[i] for i in np.argsort(distance, kind="stable")]
    return [index, *(order if count is None else order[:count])]


def _sample(image: np.ndarray, u: np.ndarray, v: np.ndarray, how=cv2.INTER_LINEAR) -> np.ndarray:
    """Bilinear samples of `image` (H, W[, C]) at float pixel positions (N,); NaN outside."""
    # OpenCV's maps are at most 32767 wide: lay the N positions out as rows of 1024.
    n = u.shape[0]
    rows = -(-n // 1024)
    grid = lambda a: np.pad(np.asarray(a, np.float32), (0, rows * 1024 - n), constant_values=-10)  # noqa: E731
    out = cv2.remap(
        np.ascontiguousarray(image, np.float32),
        grid(u).reshape(rows, 1024),
        grid(v).reshape(rows, 1024),
        how,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=np.nan,
    )
    return out.reshape(rows * 1024, *image.shape[2:])[:n]


@dataclasses.dataclass(frozen=True)
class FrameData:
    """What observing a frame needs: its image, depth and normals, the depth with NaN where
    there is no geometry, which channels are clipped (as 0/1 floats, to be sampled like the
    image), the inverse pose."""

    image: np.ndarray
    depth: np.ndarray
    normals: np.ndarray
    usable_depth: np.ndarray
    clipped: np.ndarray
    world_to_camera: np.ndarray

    @classmethod
    def of(cls, frame, saturation_level: float = 1.0) -> "FrameData":
        depth = np.where(frame.geometry_mask, frame.depth, np.nan).astype(np.float32)
        clipped = frame.image >= saturation_level  # (H, W, 3) bool
        return cls(
            frame.image, frame.depth, frame.normals, depth, clipped, np.linalg.inv(frame.pose)
        )


@dataclasses.dataclass(frozen=True)
class Observation:
    """N points seen in one frame: corners (N, 4, ...) as in `Tracks`, values (N, 3),
    whether each counts (N,: seen, no clipped channel), which of its channels count (N, 3:
    seen, that channel not clipped at any of the four corners) and its least-squares weight
    (N,; 0 where no channel counts)."""

    corner_point: np.ndarray
    corner_normal: np.ndarray
    corner_pixel: np.ndarray
    corner_weight: np.ndarray
    values: np.ndarray
    seen: np.ndarray
    channel_seen: np.ndarray
    weight: np.ndarray


# Where an observation does not count, its corners hold a harmless geometry (a point ahead
# of the camera, facing it) so that every model evaluates finitely there.
_AHEAD, _FACING = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])


def _corners(camera: Camera, data: FrameData, rows: np.ndarray, cols: np.ndarray):
    """Camera-frame points and normals of pixel centres (..., 3)."""
    depth = data.depth[rows, cols].astype(np.float64)
    point = np.stack(
        [
            depth * (cols - float(camera.cx)) / float(camera.fx),
            depth * (rows - float(camera.cy)) / float(camera.fy),
            depth,
        ],
        -1,
    )
    return point, data.normals[rows, cols].astype(np.float64)


def observe(camera: Camera, data: FrameData, world: np.ndarray, tolerance: float) -> Observation:
    """Observations of world points (N, 3) in one frame (see the module doc)."""
    rotation, translation = data.world_to_camera[:3, :3], data.world_to_camera[:3, 3]
    point = world @ rotation.T + translation
    z = point[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = float(camera.fx) * point[:, 0] / z + float(camera.cx)
        v = float(camera.fy) * point[:, 1] / z + float(camera.cy)
    inside = (z > 0) & (u >= 0) & (v >= 0) & (u <= camera.width - 1) & (v <= camera.height - 1)
    u = np.where(inside, u, -10.0)
    v = np.where(inside, v, -10.0)
    # NaN in any of the four neighbours makes the bilinear depth NaN: not usable.
    depth = _sample(data.usable_depth, u, v)
    with np.errstate(invalid="ignore"):
        seen = inside & (np.abs(depth - z) <= tolerance * z)
    values = _sample(data.image, u, v)
    seen &= np.all(np.isfinite(values), axis=-1)
    spread = np.max(np.abs(values - _sample(data.image, u, v, cv2.INTER_NEAREST)), axis=-1)
    # The four pixel centres around (u, v) and their bilinear weights.
    u0 = np.clip(np.floor(np.where(seen, u, 0)), 0, camera.width - 2).astype(int)
    v0 = np.clip(np.floor(np.where(seen, v, 0)), 0, camera.height - 2).astype(int)
    fu, fv = np.where(seen, u, 0) - u0, np.where(seen, v, 0) - v0
    cols = np.stack([u0, u0 + 1, u0, u0 + 1], -1)
    rows = np.stack([v0, v0, v0 + 1, v0 + 1], -1)
    corner_weight = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], -1)
    corner_point, corner_normal = _corners(camera, data, rows, cols)
    seen &= np.all(np.isfinite(corner_point) & np.isfinite(corner_normal), axis=(-2, -1))
    # A channel counts where none of the four corners (of nonzero weight) is clipped in it.
    clipped = data.clipped[rows, cols] & (corner_weight > 0)[..., None]  # (N, 4, 3)
    channel_seen = seen[:, None] & ~np.any(clipped, axis=1)
    return _masked(
        Observation(
            corner_point,
            corner_normal,
            np.stack([cols, rows], -1).astype(float),
            corner_weight,
            values,
            np.all(channel_seen, axis=-1),
            channel_seen,
            observation_weight(np.where(seen, spread, 0.0)),
        )
    )


def observe_own(camera: Camera, data: FrameData, rows, cols, saturation_level=1.0):
    """The anchors' own observations: their pixels, exactly (one corner of weight 1)."""
    point, normal = _corners(camera, data, rows, cols)
    values = data.image[rows, cols].astype(np.float64)
    geometry = np.all(np.isfinite(point), axis=-1) & np.all(np.isfinite(normal), axis=-1)
    channel_seen = geometry[:, None] & (values < saturation_level)
    repeat = lambda a: np.repeat(a[:, None], 4, axis=1)  # noqa: E731
    weight = np.zeros((len(rows), 4))
    weight[:, 0] = 1
    return _masked(
        Observation(
            repeat(point),
            repeat(normal),
            repeat(np.stack([cols, rows], -1).astype(float)),
            weight,
            values,
            np.all(channel_seen, axis=-1),
            channel_seen,
            np.ones(len(rows)),
        )
    )


def _masked(obs: Observation) -> Observation:
    """`obs` with the observations of which no channel counts set to the harmless geometry,
    in place (only those rows are written: most observations count)."""
    hidden = ~np.any(obs.channel_seen, axis=-1)
    obs.corner_point[hidden] = _AHEAD
    obs.corner_normal[hidden] = _FACING
    obs.corner_pixel[hidden] = 0.0
    obs.corner_weight[hidden] = 0.0
    obs.values[hidden] = 0.0
    obs.weight[hidden] = 0.0
    return obs


def world_points(camera: Camera, frame, rows, cols) -> np.ndarray:
    """World points (N, 3) of pixels of `frame` (from its depth and pose)."""
    local = points_from_depth(camera, frame.depth)[rows, cols]
    return local @ frame.pose[:3, :3].T + frame.pose[:3, 3]


def follow(
    capture,
    anchors: list[tuple[np.ndarray, np.ndarray]],
    *,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
    tolerance: float = DEFAULT_TOLERANCE,
    saturation_level: float = 1.0,
    frames=None,
) -> Tracks:
    """Tracks of the anchor pixels `anchors[f] = (rows, cols)` of every frame f (pixels with
    depth and a normal), followed into each frame's `neighbours` nearest frames (all when
    None). With `frames` (indices), only those frames' anchors, followed into those frames
    only (a held-out split). Every frame needs depth, normals and a pose (`require_poses`)."""
    require_poses(capture)
    camera = capture.camera
    frames = list(range(len(capture))) if frames is None else sorted(frames)
    count = len(frames) - 1 if neighbours is None else min(neighbours, len(frames) - 1)
    data = {i: FrameData.of(capture.frames[i], saturation_level) for i in frames}
    parts = []
    for index, (rows, cols) in enumerate(anchors):
        if index not in data:
            continue
        frame = capture.frames[index]
        rows, cols = np.asarray(rows, int), np.asarray(cols, int)
        keep = frame.geometry_mask[rows, cols]
        rows, cols = rows[keep], cols[keep]
        if len(rows) == 0:
            continue
        world = world_points(camera, frame, rows, cols)
        slots = [
            observe_own(camera, data[index], rows, cols, saturation_level)
            if other == index
            else observe(camera, data[other], world, tolerance)
            for other in partners(capture, index, count, frames)
        ]

        def stack(name, slots=slots):
            return np.stack([getattr(o, name) for o in slots], axis=1)

        seen_in = np.array(partners(capture, index, count, frames))
        parts.append(
            {
                "corner_point": stack("corner_point"),
                "corner_normal": stack("corner_normal"),
                "corner_pixel": stack("corner_pixel"),
                "corner_weight": stack("corner_weight"),
                "values": stack("values"),
                # The BRDF fit drops an observation with any clipped channel.
                "observed": stack("seen"),
                "weight": stack("weight") * stack("seen"),
                "frame": np.where(stack("seen"), seen_in[None, :], -1),
                "anchor_frame": np.full(len(rows), index),
                "anchor_row": rows,
                "anchor_col": cols,
            }
        )
    if not parts:
        raise CtjaxError(f"{capture.root}: no anchor pixel with depth and a normal to follow")
    return Tracks(**{k: np.concatenate([p[k] for p in parts]) for k in parts[0]})
