"""Do the highlights sit where the normals say N = H? And would one rotation put them there?

Under the right normals a highlight's brightest pixel lies where the surface's normal N is
along the half vector H (with the light at the lens, H = V), however rough the surface: the
lobe is largest there. `highlight_alignment` takes the peak of every connected piece of S
in every frame (its brightest pixel, or the middle of its clipped core), the angle there
between N and H, and asks whether one rotation of every normal (in world coordinates, by
the frames' poses) brings them to N = H: a tilt fitted to the first frames' peaks (robust
to those far from it: `best_tilt`) and judged on the later frames', which it has not seen.
Three outcomes:

- `aligned`: the highlights' peaks lie within `ALIGNED_DEG` of N = H (median): the shape
  places them, and an intensity fit of the lobe about these normals can see it.
- `misoriented`: one rotation brings the later frames' peaks much nearer to N = H: the
  shape's orientation is wrong by about that rotation (structure-from-motion of a nearly
  flat scene from a moving monocular video can tilt it: a plane seen by a moving camera has
  two solutions). A lobe fitted about these normals is looked for in the wrong place.
- `scattered`: the peaks lie away from N = H in no common direction that a rotation takes:
  relief finer than the reconstruction, or noisy normals (sparkles on wet tissue).

Measured (12 frames at 640 px; `benchmarks/highlight_normals.py` on the same captures): the
cholecystectomy video (monocular, guessed camera): 706 peaks, 34.0 degrees from N = H
(median; 39.3 at random pixels), a tilt of 29.7 degrees fitted on the first frames takes
the later frames' from 36.2 to 13.6: `misoriented`; the SurgT da Vinci stereo clip (each
frame's depth from its pair): 26.8 degrees (52.4 at random), the tilt fitted (12.2
degrees) takes the later frames' from 26.6 to 30.4: `scattered`; the shared sinus: 10
peaks in each part, too few to tell. The shared sinus's 35 frames at 1920x1080: the moving
highlight of frames 0-12 at 7-23 degrees, but from frame 13 a wall close to the scope,
overexposed (its reconstructed depth a fifth of the scene's), and the bright rim beside it
at 80-90 degrees: 85.3 degrees in all, 65.5 at random pixels, `misoriented` by a turn of
86.5 degrees; the reason then says the peaks lie farther from N = H than random pixels.
"""

import dataclasses
import math

import cv2
import numpy as np

from .._determined import Undetermined, add_undetermined
from .._errors import CtjaxError, ParameterError
from .._status import Status
from ..io import Capture
from ._capture_sets import MaskOptions, capture_sets
from ._specular_set import SpecularSets

# The peaks' median angle to N = H under which the shape places the highlights.
ALIGNED_DEG = 10.0
# A rotation explains the peaks' offset where it brings the later frames' median angle to at
# most this share of what it was, and by at least `MISORIENTED_MIN_GAIN_DEG`.
MISORIENTED_SHARE = 0.7
MISORIENTED_MIN_GAIN_DEG = 5.0
# Fewest highlights in each part (first frames, later frames) for a verdict.
MIN_HIGHLIGHTS = 20
# Pixels within this of a piece's brightest (linear, mean of the channels: one 8-bit level)
# share its peak (a clipped core).
PEAK_TOLERANCE = 1 / 255
# The reweighting's floor on a peak's chord |R n - h| (about 1 degree).
_CHORD_FLOOR = 0.02
# The first frames: this share of the frames (at least one, at most all but one), as the
# held-out protocol's calibration frames (`ctjax.heldout.split_frames`).
FIRST_SHARE = 0.6


@dataclasses.dataclass(frozen=True)
class HighlightPeaks:
    """The brightest pixel of each connected piece of S: its frame, pixel (x, y), and the
    surface normal and H there in world coordinates (by the frame's pose; the camera frame
    where the frame has none), each (K, 3) unit."""

    frame: np.ndarray
    pixel: np.ndarray
    normal: np.ndarray
    half: np.ndarray

    def __len__(self) -> int:
        return len(self.frame)

    def angles_deg(self, rotation: np.ndarray | None = None) -> np.ndarray:
        """The angle between N (turned by `rotation`, world) and H at each peak, degrees."""
        normal = self.normal if rotation is None else self.normal @ rotation.T
        cosine = np.clip(np.sum(normal * self.half, axis=-1), -1.0, 1.0)
        return np.degrees(np.arccos(cosine))


@dataclasses.dataclass(frozen=True)
class HighlightAlignment:
    """The peaks' angle to N = H and what one rotation of the normals does to it (module
    docstring). `highlights`: peaks in the first and in the later frames; `angle_deg`: their
    median angle to N = H, all peaks; `all_pixels_angle_deg`: the same over every pixel with
    a normal (what a peak at random would show); `rotation`: the world rotation (3x3) that
    best takes the first frames' normals at their peaks to H, and `rotation_deg` its angle;
    `later_angle_deg`: the later frames' median before and after it; `status`: `aligned`,
    `misoriented`, `scattered` or `too_few_highlights`, `reason` saying why."""

    highlights: tuple[int, int]
    angle_deg: float
    all_pixels_angle_deg: float
    rotation: np.ndarray
    rotation_deg: float
    later_angle_deg: tuple[float, float]
    status: str
    reason: str

    def to_json(self) -> dict:
        return {
            "highlights": {"first_frames": self.highlights[0], "later_frames": self.highlights[1]},
            "angle_deg_median": _rounded(self.angle_deg),
            "all_pixels_angle_deg_median": _rounded(self.all_pixels_angle_deg),
            "rotation_deg": _rounded(self.rotation_deg),
            "rotation": np.round(self.rotation, 6).tolist(),
            "later_frames_angle_deg_median": {
                "as_reconstructed": _rounded(self.later_angle_deg[0]),
                "rotated": _rounded(self.later_angle_deg[1]),
            },
            "status": self.status,
            "reason": self.reason,
        }


def _rounded(value: float) -> float | None:
    return round(float(value), 3) if math.isfinite(value) else None


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _rays(camera, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    fx, fy, cx, cy = (float(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
    return _unit(np.stack([(xs - cx) / fx, (ys - cy) / fy, np.ones_like(xs)], axis=-1))


def _turn(frame) -> np.ndarray:
    """The frame's camera-to-world rotation (the identity without a pose)."""
    return np.eye(3) if frame.pose is None else np.asarray(frame.pose, float)[:3, :3]


def _peaks(labels: np.ndarray, count: int, brightness: np.ndarray):
    """Each labelled piece's peak (rows, columns; pieces 1 to `count` - 1): among its
    pixels within `PEAK_TOLERANCE` of its brightest, the one nearest their centroid. A
    clipped core is many pixels at the top: its first pixel in raster order would sit on
    the core's upper edge, its middle is where N = H."""
    flat = labels.reshape(-1)
    inside = np.flatnonzero(flat > 0)
    label, value = flat[inside], brightness.reshape(-1)[inside]
    top = np.full(count, -np.inf)
    np.maximum.at(top, label, value)
    near = value >= top[label] - PEAK_TOLERANCE
    index, label = inside[near], label[near]
    ys, xs = np.divmod(index, labels.shape[1])
    size = np.bincount(label, minlength=count)
    cy = np.bincount(label, ys, minlength=count) / np.maximum(size, 1)
    cx = np.bincount(label, xs, minlength=count) / np.maximum(size, 1)
    distance = (ys - cy[label]) ** 2 + (xs - cx[label]) ** 2
    order = np.lexsort((distance, label))  # by piece, nearest the centroid first
    first = order[np.searchsorted(label[order], np.arange(1, count))]
    return ys[first], xs[first]


def highlight_peaks(capture: Capture, sets: list[SpecularSets], light_mm=None) -> HighlightPeaks:
    """The peak of every 8-connected piece of S, among the pixels with a normal, in every
    frame of `capture` (`sets`: one per frame): its brightest pixel (mean of the channels),
    or the middle one of its clipped core (`_peaks`). H is V's with the light at the lens;
    given `light_mm` (a point light's position in the camera frame, the capture's length
    unit), it is the half vector of the light's direction and V's at the peak's surface
    point (from the frame's depth; peaks without depth are dropped)."""
    if not capture.has_geometry:
        raise CtjaxError(f"{capture.root}: the highlights' normals need normals for every frame")
    if len(sets) != len(capture.frames):
        raise ParameterError(f"{len(sets)} specular sets for {len(capture.frames)} frames")
    frames, pixels, normals, halves = [], [], [], []
    for index, (frame, specular) in enumerate(zip(capture.frames, sets, strict=True)):
        valid = frame.geometry_mask & np.all(np.isfinite(frame.normals), axis=-1)
        if light_mm is not None:
            if frame.depth is None:
                raise CtjaxError(f"frame {frame.name}: H from a near light needs its depth")
            valid &= np.isfinite(frame.depth)
        pieces = (specular.specular & valid).astype(np.uint8)
        count, labels = cv2.connectedComponents(pieces, None, 8)
        if count < 2:
            continue
        ys, xs = _peaks(labels, count, frame.image.mean(axis=-1))
        turn = _turn(frame)
        normal = _unit(frame.normals[ys, xs].astype(np.float64))
        half = -_rays(capture.camera, xs.astype(float), ys.astype(float))
        if light_mm is not None:
            ray = half / half[:, 2:]  # -V scaled to z = 1: depth is along z
            point = ray * frame.depth[ys, xs].astype(np.float64)[:, None]
            half = _unit(half + _unit(np.asarray(light_mm, np.float64) - point))
        frames.append(np.full(len(ys), index))
        pixels.append(np.stack([xs, ys], axis=-1))
        normals.append(normal @ turn.T)
        halves.append(half @ turn.T)
    if not frames:
        empty = np.zeros((0, 3))
        return HighlightPeaks(np.zeros(0, int), np.zeros((0, 2), int), empty, empty)
    return HighlightPeaks(*(np.concatenate(a) for a in (frames, pixels, normals, halves)))


def _rotation(w: np.ndarray) -> np.ndarray:
    """The rotation by the vector `w` (axis times angle, radians; Rodrigues)."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3)
    k = w / angle
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * cross + (1 - math.cos(angle)) * cross @ cross


def best_tilt(normal: np.ndarray, half: np.ndarray) -> np.ndarray:
    """The rotation R about an axis across the mean of `half` that minimises the sum of
    |R n - h| (the chord: about the angle) over the pairs (K, 3) each: robust, as a median
    is, to the peaks far from N = H (by iteratively reweighted Gauss-Newton). A turn about
    the mean H itself barely moves normals that all lie near it (the twist is undetermined
    where the peaks sit near the image centre): only the tilt is fitted, its two angles."""
    mean = _unit(half.mean(axis=0))
    helper = np.array([1.0, 0.0, 0.0]) if abs(mean[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = _unit(np.cross(mean, helper))
    axes = np.stack([a, np.cross(mean, a)])  # (2, 3): the tilts' axes
    w = np.zeros(2)
    for _ in range(100):
        rotation = _rotation(w @ axes)
        turned = normal @ rotation.T
        root = 1 / np.sqrt(np.maximum(np.linalg.norm(turned - half, axis=-1), _CHORD_FLOOR))
        residual = ((turned - half) * root[:, None]).reshape(-1)
        # d(R n)/dw_i ~ axis_i x (R n) for a small further turn (left-multiplied).
        jacobian = np.stack(
            [(np.cross(axis, turned) * root[:, None]).reshape(-1) for axis in axes], axis=1
        )
        step = np.linalg.lstsq(jacobian, -residual, rcond=None)[0]
        new = _rotation(step @ axes) @ rotation
        w = _rotation_vector(new) @ axes.T
        if np.max(np.abs(step)) < 1e-9:
            break
    return _rotation(w @ axes)


def _rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector (axis times angle) of a rotation matrix (angle below pi)."""
    angle = math.acos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0))
    if angle < 1e-12:
        return np.zeros(3)
    r = rotation
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return axis / (2 * math.sin(angle)) * angle


def _all_pixels_angle_deg(capture: Capture, samples: int = 5000, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    angles = []
    for frame in capture.frames:
        valid = frame.geometry_mask & np.all(np.isfinite(frame.normals), axis=-1)
        ys, xs = np.nonzero(valid)
        pick = rng.choice(len(xs), min(samples, len(xs)), replace=False)
        ys, xs = ys[pick], xs[pick]
        normal = _unit(frame.normals[ys, xs].astype(np.float64))
        half = -_rays(capture.camera, xs.astype(float), ys.astype(float))
        angles.append(np.degrees(np.arccos(np.clip(np.sum(normal * half, -1), -1, 1))))
    angles = np.concatenate(angles) if angles else np.zeros(0)
    return float(np.median(angles)) if angles.size else math.nan


def first_frames(count: int) -> int:
    """How many of `count` frames are the first frames (`FIRST_SHARE`)."""
    return min(count - 1, max(1, math.ceil(FIRST_SHARE * count)))


def highlight_alignment(
    capture: Capture,
    masks: MaskOptions | None = None,
    *,
    sets: list[SpecularSets] | None = None,
    min_highlights: int | None = None,
    light_mm=None,
) -> HighlightAlignment:
    """Whether the highlights' peaks sit at N = H, and whether one rotation of the normals
    fitted on the first frames' peaks brings the later frames' there (module docstring).

    `sets`: S of every frame (default: `capture_sets(capture, masks)`); `min_highlights`:
    the fewest peaks in each part for a verdict (default `MIN_HIGHLIGHTS`); `light_mm`: a
    point light's position (camera frame, the capture's length unit) where it is not at the
    lens (`highlight_peaks`). Raises
    `CtjaxError` for a capture without normals or with fewer than 2 frames."""
    min_highlights = MIN_HIGHLIGHTS if min_highlights is None else int(min_highlights)
    if min_highlights < 1:
        raise ParameterError(f"min_highlights must be at least 1, got {min_highlights}")
    if len(capture.frames) < 2:
        raise CtjaxError(
            f"{capture.root}: the highlights' alignment is fitted on the first frames and "
            f"judged on the later ones; the capture has {len(capture.frames)} frame(s)"
        )
    if sets is None:
        sets = capture_sets(capture, MaskOptions() if masks is None else masks)
    peaks = highlight_peaks(capture, sets, light_mm)
    first = peaks.frame < first_frames(len(capture.frames))
    counts = (int(first.sum()), int((~first).sum()))
    angles = peaks.angles_deg()
    median = float(np.median(angles)) if len(peaks) else math.nan
    everywhere = _all_pixels_angle_deg(capture)
    if min(counts) < min_highlights:
        return HighlightAlignment(
            counts, median, everywhere, np.eye(3), math.nan, (math.nan, math.nan),
            "too_few_highlights",
            f"{counts[0]} highlights in the first frames and {counts[1]} in the later ones "
            f"(at least {min_highlights} each to fit a rotation on one and judge it on the "
            "other)",
        )  # fmt: skip
    rotation = best_tilt(peaks.normal[first], peaks.half[first])
    turned = math.degrees(math.acos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0)))
    before = float(np.median(angles[~first]))
    after = float(np.median(peaks.angles_deg(rotation)[~first]))
    # Peaks farther from N = H than the pixels at random: no lobe about these normals put
    # them there, whatever its width.
    away = (
        "; they lie farther from N = H than the pixels at random: the shape is wrong where "
        "they are (a wall close to the scope with no features for structure from motion, "
        "its surface extrapolated) or they are not specular (a pale wall overexposed)"
        if median > everywhere
        else ""
    )
    if median <= ALIGNED_DEG:
        status, reason = (
            "aligned",
            (
                f"the highlights' peaks lie {median:.1f} degrees from N = H (median; "
                f"{everywhere:.1f} at random pixels): the normals place them"
            ),
        )
    elif after <= MISORIENTED_SHARE * before and before - after >= MISORIENTED_MIN_GAIN_DEG:
        status, reason = (
            "misoriented",
            (
                f"the highlights' peaks lie {median:.1f} degrees from N = H (median; "
                f"{everywhere:.1f} at random pixels); one rotation of the normals by "
                f"{turned:.1f} degrees, fitted on the first frames' peaks, brings the later "
                f"frames' from {before:.1f} to {after:.1f}: the shape's orientation is off, and "
                f"a lobe about these normals is looked for in the wrong place{away}"
            ),
        )
    else:
        status, reason = (
            "scattered",
            (
                f"the highlights' peaks lie {median:.1f} degrees from N = H (median; "
                f"{everywhere:.1f} at random pixels), not in one direction: the rotation fitted to "
                f"the first frames' peaks ({turned:.1f} degrees) takes the later frames' from "
                f"{before:.1f} to {after:.1f}; relief finer than the shape, or noisy normals"
                f"{away}"
            ),
        )
    return HighlightAlignment(
        counts, median, everywhere, rotation, turned, (before, after), status, reason
    )


def highlight_alignment_summary(capture: Capture, sets: list[SpecularSets], light_mm=None) -> dict:
    """`ctjax fit`'s `highlight_alignment` block (`HighlightAlignment.to_json`); never raises
    for the capture's content: without normals, or with one frame, the block says why in
    `status` (`not_measured`) and `reason`."""
    try:
        return highlight_alignment(capture, sets=sets, light_mm=light_mm).to_json()
    except CtjaxError as error:
        return {"status": "not_measured", "reason": str(error)}


def flag_misoriented(estimate, capture: Capture, sets: list[SpecularSets], light_mm=None):
    """`estimate` (a fit with a specular lobe, on `capture` with the sets `sets`) with its
    highlights' alignment in `details["highlight_alignment"]` and, where they are
    `misoriented`, its lobe flagged as no measurement (`Status.misoriented`, a warning: the
    lobe was fitted about normals that misplace the highlights)."""
    block = highlight_alignment_summary(capture, sets, light_mm)
    estimate.details["highlight_alignment"] = block
    if block["status"] == "misoriented":
        reason = f"{block['reason']} (ctjax.specular.highlight_alignment)"
        add_undetermined(estimate, Undetermined("sigma", Status.misoriented, reason))
    return estimate


def highlight_alignment_line(block: dict) -> str:
    """One line of `ctjax fit`'s output for its `highlight_alignment` block."""
    return f"highlight alignment: {block['status']}: {block['reason']}"
