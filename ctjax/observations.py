"""A capture as observations: what the estimators consume, built once and passed down.

`Observations.of(capture)` gathers, per frame, the usable pixels (geometry, no clipped
channel), the view direction of every pixel, the camera-frame points, and (on first use) the
specular set S, its ring S~ and the saturated pixels; the estimators take them instead of
going back to the frames: pixel samples for the general fitter (`pixels`), the ring's
shading samples under the paper's light for the BnB (`ring`), the working distance. Every
public estimator accepts a `Capture` or its `Observations`.
"""

import dataclasses
import functools
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._camera import Camera
from ._convert import on_device
from ._errors import CtjaxError, ParameterError
from ._geometry import points_from_depth
from ._typing import Array, Float, Int
from ._units import length_unit_of
from ._vector import Vec3
from .io import Capture


class PixelSamples(eqx.Module):
    """N pixels: camera-frame point (mm) and unit normal, pixel (u, v), measured linear RGB
    (1.0 = 8-bit level 255), and the index of the frame and (row, col) they come from."""

    point: Vec3
    normal: Vec3
    pixel: tuple[Float[Array, " N"], Float[Array, " N"]]
    values: Float[Array, "N 3"]
    frame: Int[Array, " N"]
    row: Int[Array, " N"]
    col: Int[Array, " N"]

    def __len__(self) -> int:
        return self.values.shape[0]


class ShadingSamples(eqx.Module):
    """N pixels: unit normal, light and view directions (camera frame), the irradiance
    factor of the light there, and the measured linear RGB (1.0 = 8-bit level 255)."""

    normal: Vec3
    light: Vec3
    view: Vec3
    irradiance: Float[Array, " N"]
    values: Float[Array, "N 3"]

    def __check_init__(self):
        n = self.values.shape[0]
        if self.values.ndim != 2 or self.values.shape[1] != 3:
            raise ParameterError(f"sample values must be (N, 3) RGB, got {self.values.shape}")
        for name in ("normal", "light", "view"):
            for part in (getattr(self, name).x, getattr(self, name).y, getattr(self, name).z):
                if jnp.shape(part) != (n,):
                    raise ParameterError(f"sample {name} must have {n} entries per component")
        if jnp.shape(self.irradiance) != (n,):
            raise ParameterError(f"sample irradiance must have shape ({n},)")

    def __len__(self) -> int:
        return self.values.shape[0]


# Tracks for the albedo map: anchored within this many pixels of S, at most this many points
# (the count lands within a few hundred of it: just under the bucket 32768, `ctjax._buckets`;
# 40000 was padded to 49152, a quarter of the sigma search's work on nothing: 640x512 x 8
# fits 1.26-1.33 s -> 1.03-1.05 s, the same sigma and F_tilde to 0.05%; on the demo's SfM
# capture sigma +3.6% against +3.9%, F_tilde 0..+1.9% against -1.2..+0.7%).
DEFAULT_TRACK_RADIUS_PX = 12.0
DEFAULT_MAX_TRACKS = 16_000
# The fewest surface points the albedo map is asked to follow: each point's albedo is told
# from the BRDF by its views in several frames, and a frame's share of a handful of points
# rounds to none (`--max-tracks 1` ended in "no anchor pixel").
MIN_TRACKS = 100
DEFAULT_NEIGHBOURS = 12  # = ctjax._tracks.DEFAULT_NEIGHBOURS


@functools.lru_cache(maxsize=4)
def _z_order(shape: tuple[int, int]) -> np.ndarray:
    """The flat indices of an image's pixels in Z-order (Morton: the bits of row and column
    interleaved; images up to 65536 pixels wide and high)."""

    def spread(x):  # bit k of x to bit 2k
        x = x.astype(np.uint64)
        for shift, mask in ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)):
            x = (x | (x << np.uint64(shift))) & np.uint64(mask)
        return x

    rows, cols = np.divmod(np.arange(shape[0] * shape[1]), shape[1])
    order = np.argsort(spread(cols) | (spread(rows) << np.uint64(1)), kind="stable")
    order.flags.writeable = False
    return order


def _pixels(shape: tuple[int, int], flat: np.ndarray) -> np.ndarray:
    """The (H, W) mask of the pixels at `flat` indices."""
    mask = np.zeros(shape, bool)
    mask.reshape(-1)[flat] = True
    return mask


def _evenly(mask: np.ndarray, count: int, rng) -> np.ndarray:
    """`count` of the pixels of `mask` (H, W), as sorted flat indices: evenly spaced along
    the Z-order curve from a random offset, i.e. spread evenly over the image (a
    stratified sample: on a capture with SfM's shape, half the spread of the fitted sigma
    and F_tilde over draws of independent random ones)."""
    order = _z_order(mask.shape)
    inside = order[mask.reshape(-1)[order]]
    count = min(count, len(inside))
    if count <= 0:
        return np.zeros(0, int)
    step = len(inside) / count
    return np.sort(inside[np.floor(rng.uniform(0, step) + step * np.arange(count)).astype(int)])


def concatenate(samples: list[ShadingSamples]) -> ShadingSamples:
    return jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *samples)


def usable_mask(frame, saturation_level=1.0) -> np.ndarray:
    """Pixels with geometry (finite positive depth and normal) and no clipped channel: none
    at or above `saturation_level` (one level, or one per channel: `Capture.saturation`)."""
    if frame.depth is None or frame.normals is None:
        raise CtjaxError(
            f"frame {frame.name}: needs depth (and normals) to compare the model"
            " (`ctjax reconstruct CAPTURE` estimates them from the images)"
        )
    return frame.geometry_mask & np.all(frame.image < saturation_level, axis=-1)


def view_directions(camera, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Unit directions (..., 3) from the surface point seen at each pixel towards the camera.

    Along the pixel's ray, so they do not need depth.
    """
    ray = np.stack(
        [
            (cols - float(camera.cx)) / float(camera.fx),
            (rows - float(camera.cy)) / float(camera.fy),
            np.ones(np.shape(rows)),
        ],
        axis=-1,
    )
    return -ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def colocated_samples(
    camera: Camera, image: np.ndarray, normals: np.ndarray, mask: np.ndarray, dtype=None
) -> ShadingSamples:
    """Samples of the pixels in `mask` under the paper's light: L = V, unit irradiance.

    `dtype` defaults to JAX's default float (float64 when x64 is enabled, as the CLI does).
    """
    if dtype is None:
        dtype = jax.dtypes.canonicalize_dtype(np.float64)
    rows, cols = np.nonzero(mask)
    view = view_directions(camera, rows.astype(float), cols.astype(float)).astype(dtype)
    normal = normals[rows, cols].astype(dtype)
    v = Vec3.from_array(jnp.asarray(view))
    return ShadingSamples(
        Vec3.from_array(jnp.asarray(normal)),
        v,
        v,
        jnp.ones(len(rows), dtype),
        jnp.asarray(image[rows, cols], dtype),
    )


def capture_samples(
    capture, frames, *, max_samples: int | None = None, seed: int = 0, dtype=None
) -> PixelSamples:
    """`Observations.of(capture).pixels(frames, ...)`: the usable pixels of `frames`."""
    return Observations.of(capture).pixels(frames, max_samples=max_samples, seed=seed, dtype=dtype)


def _float(dtype):
    return jax.dtypes.canonicalize_dtype(np.float64) if dtype is None else dtype


@dataclasses.dataclass(eq=False)
class Observations:
    """The frames of `capture` as the estimators see them (see the module).

    `masks` are the options of S and S~ (`ctjax.estimation.MaskOptions`; the paper's by
    default), used the first time `sets` is read.
    """

    capture: Capture
    masks: object = None
    _tracks: dict = dataclasses.field(default_factory=dict, init=False, repr=False)

    @classmethod
    def of(cls, capture: "Capture | Observations", masks=None) -> "Observations":
        """`capture`'s observations (itself when it already is; new `masks` make new sets)."""
        if isinstance(capture, Observations):
            if masks is None or masks == capture.masks:
                return capture
            capture = capture.capture
        return cls(capture, masks)

    # The capture's own attributes, so that observations stand in for it where only those
    # are read (the root in messages, the camera, the frames, their clipping, the count).
    @property
    def root(self):
        return self.capture.root

    @property
    def camera(self):
        return self.capture.camera

    @property
    def frames(self):
        return self.capture.frames

    @property
    def saturation(self):
        return self.capture.saturation

    def __len__(self) -> int:
        return len(self.capture)

    @functools.cached_property
    def usable(self) -> list[np.ndarray]:
        """Per frame (H, W): geometry and no clipped channel (see `usable_mask`)."""
        level = np.asarray(self.capture.saturation)
        return [usable_mask(frame, level) for frame in self.capture.frames]

    @functools.cached_property
    def view(self) -> np.ndarray:
        """(H, W, 3): each pixel's unit view direction, the same in every frame."""
        camera = self.capture.camera
        rows, cols = np.mgrid[0 : camera.height, 0 : camera.width]
        return view_directions(camera, rows.astype(float), cols.astype(float))

    @functools.cached_property
    def sets(self) -> list:
        """Per frame: S, S~ and the saturated pixels (`SpecularSets`)."""
        from .specular import MaskOptions, capture_sets

        return capture_sets(self.capture, self.masks or MaskOptions())

    def clipped_note(self) -> str:
        """How much of the frames is clipped, for an error that too few views were left: a
        saturated capture's cause in numbers (empty where under a tenth of every frame)."""
        shares = [
            float(np.mean((s.saturated | s.specular)[f.geometry_mask]))
            for f, s in zip(self.capture.frames, self.sets, strict=True)
            if f.geometry_mask.any()
        ]
        if not shares or max(shares) < 0.1:
            return ""
        low, high = min(shares), max(shares)
        spread = f" ({low:.0%}-{high:.0%} per frame)" if high - low >= 0.01 else ""
        return (
            f"; {np.mean(shares):.0%} of the pixels with geometry are clipped or in S{spread}: "
            "the exposure may be too high for these views"
        )

    def specular_distance(self, index: int) -> np.ndarray:
        """(H, W): each pixel's distance (px) to the nearest pixel of S in frame `index` (inf
        in a frame without S)."""
        import cv2

        specular = self.sets[index].specular
        if not specular.any():
            return np.full(specular.shape, np.inf, np.float32)
        return cv2.distanceTransform((~specular).astype(np.uint8), cv2.DIST_L2, 5)

    def points(self, index: int) -> np.ndarray:
        """(H, W, 3): frame `index`'s camera-frame points (mm), NaN without depth."""
        return points_from_depth(self.capture.camera, self.capture.frames[index].depth)

    def median_depth_mm(self) -> float:
        """Median depth (mm) of every frame's usable pixels: the working distance."""
        depth = np.concatenate(
            [f.depth[u] for f, u in zip(self.capture.frames, self.usable, strict=True)]
        )
        if depth.size == 0:
            raise CtjaxError(f"{self.capture.root}: no usable pixel with depth")
        return float(np.median(depth))

    def candidate_context(self) -> dict:
        """What a candidate effect needs to know of the capture to start its parameters
        (`AbstractCandidate.__call__`): the working distance, the length unit, the number
        of frames, the principal point and the focal length (px)."""
        camera = self.capture.camera
        return {
            "median_depth_mm": self.median_depth_mm(),
            "length_unit": length_unit_of(self.capture),
            "frames": len(self.capture.frames),
            "principal_point": (float(camera.cx), float(camera.cy)),
            "focal_px": (float(camera.fx), float(camera.fy)),
        }

    def pixels(
        self, frames, *, max_samples: int | None = None, seed: int = 0, dtype=None
    ) -> PixelSamples:
        """The usable pixels of `frames` (indices), optionally a random subset of at most
        `max_samples` (deterministic for a seed), as `PixelSamples` for the fitters."""
        frames = list(frames)
        found = [(i, *np.nonzero(self.usable[i])) for i in frames]
        total = sum(len(rows) for _, rows, _ in found)
        if total == 0:
            raise CtjaxError(
                f"{self.capture.root}: no usable pixel (geometry and unsaturated) in frames "
                f"{frames}"
            )
        index = np.concatenate([np.full(len(r), i) for i, r, _ in found])
        rows = np.concatenate([r for _, r, _ in found])
        cols = np.concatenate([c for _, _, c in found])
        if max_samples is not None and total > max_samples:
            keep = np.sort(np.random.default_rng(seed).choice(total, max_samples, replace=False))
            index, rows, cols = index[keep], rows[keep], cols[keep]
        gather = lambda name: np.concatenate(  # noqa: E731
            [
                getattr(self.capture.frames[i], name)[rows[index == i], cols[index == i]]
                for i in dict.fromkeys(index.tolist())  # frames in the order given
            ]
        )
        depth, normals, values = gather("depth"), gather("normals"), gather("image")
        camera = self.capture.camera
        u, v = cols.astype(np.float64), rows.astype(np.float64)
        x = depth * (u - float(camera.cx)) / float(camera.fx)
        y = depth * (v - float(camera.cy)) / float(camera.fy)
        as_array = lambda a: on_device(a, _float(dtype))  # noqa: E731
        return PixelSamples(
            Vec3(as_array(x), as_array(y), as_array(depth)),
            Vec3.from_array(as_array(normals)),
            (as_array(u), as_array(v)),
            as_array(values),
            on_device(index),
            on_device(rows),
            on_device(cols),
        )

    def tracks(
        self,
        *,
        radius_px: float = DEFAULT_TRACK_RADIUS_PX,
        max_points: int | None = DEFAULT_MAX_TRACKS,
        neighbours: int | None = DEFAULT_NEIGHBOURS,
        tolerance: float | None = None,
        seed: int = 0,
        frames: Sequence[int] | None = None,
        anchor_frames: Sequence[int] | None = None,
    ):
        """Surface points followed across frames (`ctjax._tracks.Tracks`): the albedo map's
        samples. Anchored at every pixel with geometry within `radius_px` of S in each frame
        (S itself included: saturated there, seen elsewhere), where the specular lobe is
        measured, plus as many spread evenly over the rest of the frame; at most
        `max_points` in all (each frame's anchors thinned by the same fraction, evenly over
        the frame: `_evenly`; deterministic for a seed). Each is
        followed into its frame's `neighbours` nearest frames (all by default) within the
        relative depth `tolerance` (`ctjax._tracks.DEFAULT_TOLERANCE`). `frames`: only
        these frames' points, followed into these frames only (one side of a held-out
        split); `anchor_frames`: only these frames' points, followed into every frame."""
        from . import _tracks

        _tracks.require_poses(self.capture)
        if max_points is not None and not max_points >= MIN_TRACKS:
            raise ParameterError(
                f"{self.root}: {max_points} surface points to follow is too few for the albedo "
                f"map (at least {MIN_TRACKS}: each point's albedo is told from the BRDF by its "
                "views in several frames); ask for more (--max-tracks, --max-samples)"
            )
        # Built once per request: the held-out split, the noise floor and the fits of one
        # command ask for the same tracks of the same observations.
        key = (radius_px, max_points, neighbours, tolerance, seed)
        key += tuple(
            None if f is None else tuple(int(i) for i in f) for f in (frames, anchor_frames)
        )
        if key not in self._tracks:
            self._tracks[key] = self._follow(
                radius_px, max_points, neighbours, tolerance, seed, frames, anchor_frames
            )
        return self._tracks[key]

    def _follow(self, radius_px, max_points, neighbours, tolerance, seed, frames, anchor_frames):
        from . import _tracks
        from ._point_normals import one_normal_per_point
        from .io._field_of_view import black_frames

        if black_frames(self.capture):  # not "no anchor pixel with depth and a normal"
            raise CtjaxError(black_frames(self.capture))
        rng = np.random.default_rng(seed)
        anchors = []
        chosen_frames = range(len(self)) if frames is None else frames
        if anchor_frames is not None:
            chosen_frames = [i for i in chosen_frames if i in anchor_frames]
        for index, frame in enumerate(self.capture.frames):
            geometry = frame.geometry_mask
            if index not in chosen_frames:
                geometry = np.zeros_like(geometry)
            near = geometry & (self.specular_distance(index) <= radius_px)
            # As many elsewhere as near S (a frame without S: its share of `max_points`).
            share = (max_points or DEFAULT_MAX_TRACKS) // (2 * len(self))
            wanted = int(near.sum()) if near.any() else share
            anchors.append(near | _pixels(geometry.shape, _evenly(geometry & ~near, wanted, rng)))
        total = sum(int(mask.sum()) for mask in anchors)
        if max_points is not None and total > max_points:
            keep = max_points / total
            anchors = [_pixels(m.shape, _evenly(m, int(keep * m.sum()), rng)) for m in anchors]
        anchors = [np.nonzero(mask) for mask in anchors]
        options = {} if tolerance is None else {"tolerance": tolerance}
        followed = _tracks.follow(
            self.capture, anchors, neighbours=neighbours, frames=frames, **options
        )
        return one_normal_per_point(followed, self.capture)

    def ring(self, dtype=None) -> ShadingSamples:
        """Every frame's ring S~ under the paper's light (L = V, unit irradiance): the BnB's
        samples."""
        parts = []
        for frame, s in zip(self.capture.frames, self.sets, strict=True):
            if not s.ring.any():
                continue
            rows, cols = np.nonzero(s.ring)
            v = Vec3.from_array(on_device(self.view[rows, cols], _float(dtype)))
            parts.append(
                ShadingSamples(
                    Vec3.from_array(on_device(frame.normals[rows, cols], _float(dtype))),
                    v,
                    v,
                    on_device(np.ones(len(rows)), _float(dtype)),
                    on_device(frame.image[rows, cols], _float(dtype)),
                )
            )
        return concatenate(parts)
