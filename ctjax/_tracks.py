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
    and column. `corner_eye` (P, M, 4, 3), where some views are from a camera away from
    the light's lens (a stereo scope's right camera, `ctjax._right_views`): that camera's
    centre in the observation's frame (0 for the lens's own views); None where all are.
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
    corner_eye: np.ndarray | None = None  # (P, M, 4, 3)

    def __len__(self) -> int:
        return self.observed.shape[0]

    @property
    def views(self) -> np.ndarray:
        """(P,) number of frames each point is observed in."""
        return self.observed.sum(axis=1)

    def select(self, keep: np.ndarray) -> "Tracks":
        """The tracks at index or mask `keep`."""
        parts = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return Tracks(**{k: None if a is None else a[keep] for k, a in parts.items()})

    def padded(self, size: int) -> "Tracks":
        """These tracks with unobserved points appended up to `size` points (ahead of the
        camera and facing it: a finite geometry with weight 0), so that captures of similar
        size share the fitters' compiled programs."""
        extra = size - len(self)
        if extra <= 0:
            return self
        fill = {"corner_point": (0.0, 0.0, 1.0), "corner_normal": (0.0, 0.0, -1.0), "frame": -1}
        parts = {}
        for field in dataclasses.fields(self):
            array = getattr(self, field.name)
            if array is None:
                parts[field.name] = None
                continue
            pad = np.zeros((extra, *array.shape[1:]), array.dtype)
            pad[...] = fill.get(field.name, 0)
            parts[field.name] = np.concatenate([array, pad])
        return Tracks(**parts)


def views_first(array: np.ndarray) -> np.ndarray:
    """Per-observation data laid out as the fitters use it, points last: (P, M) -> (M, P),
    (P, M, K) -> (K, M, P) (corners or channels, then views), and corner vectors
    (P, M, 4, D) -> (4 M P, D) flattened in that order.

    A point's sums over its views are then sums of contiguous rows, which XLA's CPU code
    vectorises; points first, they are sums of 5-12 neighbours along the minor axis, and
    the variable projection ran 7x slower (63 ms against 9 ms for 4 sigmas on 49k points x
    5 views)."""
    if array.ndim == 2:
        return np.ascontiguousarray(array.T)
    moved = np.ascontiguousarray(np.moveaxis(array, (0, 2), (2, 0)))
    return moved if array.ndim == 3 else moved.reshape(-1, array.shape[-1])


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


def sample_image(
    image: np.ndarray, u: np.ndarray, v: np.ndarray, how=cv2.INTER_LINEAR
) -> np.ndarray:
    """Bilinear samples of `image` (H, W[, C]) at float pixel positions (N,); NaN outside."""
    # OpenCV's maps are at most 32767 wide: lay the N positions out as rows of 1024.
    n = u.shape[0]
    rows = -(-n // 1024)

    def grid(a):  # (np.pad costs 30 us a call, which adds up over frames and views)
        out = np.full((rows, 1024), -10, np.float32)
        out.reshape(-1)[:n] = a
        return out

    out = cv2.remap(
        np.ascontiguousarray(image, np.float32),
        grid(u),
        grid(v),
        how,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=np.nan,
    )
    return out.reshape(rows * 1024, *image.shape[2:])[:n]


@dataclasses.dataclass(frozen=True)
class FrameData:
    """What observing a frame needs: its image, depth and normals, the depth with NaN where
    there is no geometry, per pixel whether depth and normal are finite and which channels
    are clipped (bit c: channel c), the inverse pose."""

    image: np.ndarray
    depth: np.ndarray
    normals: np.ndarray
    usable_depth: np.ndarray
    finite: np.ndarray
    clipped_bits: np.ndarray
    world_to_camera: np.ndarray

    @classmethod
    def of(cls, frame, saturation_level=1.0) -> "FrameData":
        """`frame`'s data, its values at or above `saturation_level` (one level, or one per
        channel: `Capture.saturation`) clipped."""
        depth = np.where(frame.geometry_mask, frame.depth, np.nan).astype(np.float32)
        finite = np.isfinite(frame.depth) & _all_last(np.isfinite(frame.normals))
        clipped = frame.image >= saturation_level  # (H, W, 3) bool
        bits = sum(clipped[..., c].astype(np.uint8) << c for c in range(clipped.shape[-1]))
        return cls(
            frame.image,
            frame.depth,
            frame.normals,
            depth,
            finite,
            bits,
            np.linalg.inv(frame.pose),
        )


def _any_last(x: np.ndarray) -> np.ndarray:
    """`np.any(x, axis=-1)` for a short last axis, as elementwise ors (NumPy reduces a
    short minor axis several times slower)."""
    out = x[..., 0]
    for k in range(1, x.shape[-1]):
        out = out | x[..., k]
    return out


def _all_last(x: np.ndarray) -> np.ndarray:
    """`np.all(x, axis=-1)` for a short last axis (see `_any_last`)."""
    out = x[..., 0]
    for k in range(1, x.shape[-1]):
        out = out & x[..., k]
    return out


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


def _corners(camera: Camera, data: FrameData, index: np.ndarray):
    """Camera-frame points and normals (..., 3) of the pixel centres at flat `index`."""
    rows, cols = np.divmod(index, camera.width)
    # (`np.take`: 4-5x faster than fancy indexing for these (N, 4) gathers.)
    depth = np.take(data.depth.reshape(-1), index).astype(np.float64)
    point = np.empty((*index.shape, 3))
    point[..., 0] = depth * (cols - float(camera.cx)) / float(camera.fx)
    point[..., 1] = depth * (rows - float(camera.cy)) / float(camera.fy)
    point[..., 2] = depth
    normal = np.take(data.normals.reshape(-1, 3), index, axis=0).astype(np.float64)
    return point, normal


def _channels_seen(seen: np.ndarray, bits: np.ndarray, channels: int) -> np.ndarray:
    """(N, C): `seen` and channel c's bit not set in `bits` (N,)."""
    # (Channel by channel: 3.5x faster than broadcasting (N, 1) >> (C,) at 327k points.)
    out = np.empty((len(seen), channels), bool)
    for c in range(channels):
        np.equal(bits & np.uint8(1 << c), 0, out=out[:, c])
        out[:, c] &= seen
    return out


@dataclasses.dataclass(frozen=True)
class Sighting:
    """N points sighted in one frame, before the model's corners (`observe` adds them): the
    position (u, v) they project to (N,), the four pixel centres around it (flat indices,
    N x 4) and their bilinear weights, the bilinear values (N, 3; 0 where no channel
    counts), whether each counts (N,), which channels count (N, 3) and the least-squares
    weight (N,; 0 where no channel counts)."""

    u: np.ndarray
    v: np.ndarray
    index: np.ndarray
    corner_weight: np.ndarray
    values: np.ndarray
    seen: np.ndarray
    channel_seen: np.ndarray
    weight: np.ndarray


def _counted(sighting: Sighting) -> Sighting:
    """`sighting` with values and weight 0 where no channel counts, in place."""
    hidden = ~_any_last(sighting.channel_seen)
    sighting.values[hidden] = 0.0
    sighting.weight[hidden] = 0.0
    sighting.corner_weight[hidden] = 0.0
    return sighting


def sight(camera: Camera, data: FrameData, world: np.ndarray, tolerance: float) -> Sighting:
    """World points (N, 3) sighted in one frame (see the module doc)."""
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
    depth = sample_image(data.usable_depth, u, v)
    with np.errstate(invalid="ignore"):
        seen = inside & (np.abs(depth - z) <= tolerance * z)
    values = sample_image(data.image, u, v)
    # How far the bilinear value is from the nearest pixel's (NaN where either is).
    spread = np.abs(values - sample_image(data.image, u, v, cv2.INTER_NEAREST))
    spread = np.maximum(np.maximum(spread[:, 0], spread[:, 1]), spread[:, 2])
    seen &= np.isfinite(spread)
    # The four pixel centres around (u, v) and their bilinear weights.
    # (Where seen, u and v are >= 0: truncation is the floor, in one pass fewer.)
    seen_u, seen_v = np.where(seen, u, 0), np.where(seen, v, 0)
    u0 = np.minimum(seen_u.astype(int), camera.width - 2)
    v0 = np.minimum(seen_v.astype(int), camera.height - 2)
    fu, fv = seen_u - u0, seen_v - v0
    index = (v0 * camera.width + u0)[:, None] + np.array([0, 1, camera.width, camera.width + 1])
    corner_weight = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], -1)
    seen &= _all_last(np.take(data.finite.reshape(-1), index))
    # A channel counts where none of the four corners (of nonzero weight) is clipped in it.
    bits = np.take(data.clipped_bits.reshape(-1), index) * (corner_weight > 0)
    channel_seen = _channels_seen(seen, _any_last(bits), values.shape[-1])
    weight = observation_weight(np.where(seen, spread, 0.0))
    return _counted(
        Sighting(u, v, index, corner_weight, values, _all_last(channel_seen), channel_seen, weight)
    )


def sight_own(data: FrameData, rows, cols) -> Sighting:
    """The anchors' own sightings: their pixels, exactly (one corner of weight 1)."""
    width = data.depth.shape[1]
    values = data.image[rows, cols].astype(np.float64)
    clipped = data.clipped_bits[rows, cols][:, None] >> np.arange(values.shape[-1]) & 1
    channel_seen = data.finite[rows, cols][:, None] & (clipped == 0)
    corner_weight = np.zeros((len(rows), 4))
    corner_weight[:, 0] = 1
    index = np.repeat((rows * width + cols)[:, None], 4, axis=1)
    return _counted(
        Sighting(
            cols.astype(float),
            rows.astype(float),
            index,
            corner_weight,
            values,
            _all_last(channel_seen),
            channel_seen,
            np.ones(len(rows)),
        )
    )


def _observation(camera: Camera, data: FrameData, sighting: Sighting) -> Observation:
    """`sighting` with the model's corners (camera-frame points, normals, pixels)."""
    corner_point, corner_normal = _corners(camera, data, sighting.index)
    rows, cols = np.divmod(sighting.index, camera.width)
    return _masked(
        Observation(
            corner_point,
            corner_normal,
            np.stack([cols, rows], -1).astype(float),
            sighting.corner_weight,
            sighting.values,
            sighting.seen,
            sighting.channel_seen,
            sighting.weight,
        )
    )


def observe(camera: Camera, data: FrameData, world: np.ndarray, tolerance: float) -> Observation:
    """Observations of world points (N, 3) in one frame (see the module doc)."""
    return _observation(camera, data, sight(camera, data, world, tolerance))


def observe_own(camera: Camera, data: FrameData, rows, cols):
    """The anchors' own observations: their pixels, exactly (one corner of weight 1)."""
    return _observation(camera, data, sight_own(data, rows, cols))


def _masked(obs: Observation) -> Observation:
    """`obs` with the observations of which no channel counts set to the harmless geometry,
    in place (only those rows are written: most observations count)."""
    hidden = ~_any_last(obs.channel_seen)
    obs.corner_point[hidden] = _AHEAD
    obs.corner_normal[hidden] = _FACING
    obs.corner_pixel[hidden] = 0.0
    return obs


def world_points(camera: Camera, frame, rows, cols) -> np.ndarray:
    """World points (N, 3) of pixels of `frame` (from its depth and pose)."""
    z = frame.depth[rows, cols].astype(np.float64)  # (those pixels only, not the frame's)
    local = np.stack(
        [
            z * (cols - float(camera.cx)) / float(camera.fx),
            z * (rows - float(camera.cy)) / float(camera.fy),
            z,
        ],
        axis=-1,
    )
    return local @ frame.pose[:3, :3].T + frame.pose[:3, 3]


def follow(
    capture,
    anchors: list[tuple[np.ndarray, np.ndarray]],
    *,
    neighbours: int | None = DEFAULT_NEIGHBOURS,
    tolerance: float = DEFAULT_TOLERANCE,
    saturation_level=None,
    frames=None,
) -> Tracks:
    """Tracks of the anchor pixels `anchors[f] = (rows, cols)` of every frame f (pixels with
    depth and a normal), followed into each frame's `neighbours` nearest frames (all when
    None). With `frames` (indices), only those frames' anchors, followed into those frames
    only (a held-out split). Every frame needs depth, normals and a pose (`require_poses`).
    The views keep their frames' own normals (`ctjax._point_normals.one_normal_per_point`
    makes them one, as `Observations.tracks` does). A channel's values at or above
    `saturation_level` (one, or one per channel; default: `capture.saturation`, full scale
    or the camera's ceiling) are clipped."""
    require_poses(capture)
    camera = capture.camera
    if saturation_level is None:  # the capture's: its channels' ceilings
        saturation_level = np.asarray(capture.saturation, np.float32)
    frames = list(range(len(capture))) if frames is None else sorted(frames)
    count = len(frames) - 1 if neighbours is None else min(neighbours, len(frames) - 1)
    data = {i: FrameData.of(capture.frames[i], saturation_level) for i in frames}
    followed = []  # (anchor frame, rows, cols, the frames it is looked for in, observations)
    world = []
    for index, (rows, cols) in enumerate(anchors):
        if index not in data:
            continue
        frame = capture.frames[index]
        rows, cols = np.asarray(rows, int), np.asarray(cols, int)
        keep = frame.geometry_mask[rows, cols]
        rows, cols = rows[keep], cols[keep]
        if len(rows) == 0:
            continue
        seen_in = partners(capture, index, count, frames)
        followed.append((index, rows, cols, seen_in, [None] * len(seen_in)))
        world.append(world_points(camera, frame, rows, cols))
    if not followed:
        raise CtjaxError(f"{capture.root}: no anchor pixel with depth and a normal to follow")
    # Each frame is sighted once for the anchors of every frame that looks in it (sighting
    # frame by frame, a few thousand anchors each, was mostly NumPy's per-call overhead).
    bounds = np.cumsum([0, *(len(rows) for _, rows, _, _, _ in followed)])
    everywhere = np.concatenate(world)
    for other in frames:
        away = []  # (anchor, slot) of the anchors looked for in `other`, not their own frame
        for j, (index, rows, cols, seen_in, slots) in enumerate(followed):
            if other not in seen_in:
                continue
            if index == other:
                slots[seen_in.index(other)] = observe_own(camera, data[other], rows, cols)
            else:
                away.append((j, seen_in.index(other)))
        if not away:
            continue
        where = np.concatenate([np.arange(bounds[j], bounds[j + 1]) for j, _ in away])
        seen = observe(camera, data[other], everywhere[where], tolerance)
        start = 0
        for j, slot in away:
            size = bounds[j + 1] - bounds[j]
            followed[j][4][slot] = _part(seen, start, start + size)
            start += size
    return _assembled(followed)


def _part(obs: Observation, start: int, stop: int) -> Observation:
    """Observations `start` to `stop` of `obs` (views, not copies)."""
    return Observation(
        *(getattr(obs, field.name)[start:stop] for field in dataclasses.fields(Observation))
    )


def _assembled(followed) -> Tracks:
    """`Tracks` of the observations `follow` made, written once into arrays of their final
    size (stacking per frame and then concatenating copied each twice: 0.06 s of 0.18)."""
    points, views = sum(len(rows) for _, rows, _, _, _ in followed), len(followed[0][3])
    example = followed[0][4][0]
    source = {
        "corner_point": "corner_point",
        "corner_normal": "corner_normal",
        "corner_pixel": "corner_pixel",
        "corner_weight": "corner_weight",
        "values": "values",
        "observed": "seen",
        "weight": "weight",
    }
    out = {}
    for name, attribute in source.items():
        like = getattr(example, attribute)
        out[name] = np.empty((points, views, *like.shape[1:]), like.dtype)
    out["frame"] = np.empty((points, views), int)
    anchor = {name: np.empty(points, int) for name in ("anchor_frame", "anchor_row", "anchor_col")}
    start = 0
    for index, rows, cols, seen_in, slots in followed:
        part = slice(start, start + len(rows))
        for m, (obs, other) in enumerate(zip(slots, seen_in, strict=True)):
            for name in ("corner_point", "corner_normal", "corner_pixel", "corner_weight"):
                out[name][part, m] = getattr(obs, name)
            out["values"][part, m] = obs.values
            # The BRDF fit drops an observation with any clipped channel.
            out["observed"][part, m] = obs.seen
            out["weight"][part, m] = obs.weight * obs.seen
            out["frame"][part, m] = np.where(obs.seen, other, -1)
        anchor["anchor_frame"][part] = index
        anchor["anchor_row"][part] = rows
        anchor["anchor_col"][part] = cols
        start += len(rows)
    return Tracks(**out, **anchor)
