"""The capture format: the one input of every ctjax command.

    CAPTURE/
      camera.json          {"width", "height", "fx", "fy", "cx", "cy"} (+ optional k1 k2 p1
                           p2 k3, k4 k5 k6, "encoding": "srgb" or "linear")
      images/NAME.png      8- or 16-bit RGB, decoded to linear intensity in [0, 1]
      depth/NAME.npy       optional, float32 (H, W) camera-frame z in mm, NaN where unknown
      normals/NAME.npy     optional, float32 (H, W, 3) unit normals, camera frame, facing the camera
      poses.json           optional, {"NAME": 4x4 camera-to-world, rigid}
      right/NAME.png       optional, a stereo laparoscope's right image (camera.json's
                           "stereo" block: the right camera, R and T; `ctjax.io._stereo`)
      excluded/NAME.png    optional, the pixels that are not tissue (instruments; non-zero),
                           out of the field of view (`ctjax.io._excluded`); excluded.png:
                           in every frame
      truth.json           optional, ground truth of synthetic captures

Frames are the images, sorted by name; depth, normals and poses are matched by NAME.
Images are decoded with their encoding (`ctjax.io._encoding`): camera.json's `"encoding"`,
or, where it does not say, sRGB for 8-bit images (with a note in `Capture.notes`) and linear
for 16-bit ones. Near-white that the camera turned grey reads as clipped (1.0;
`ctjax.io._desaturated`, with a note).
"""

import dataclasses
import functools
import json
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from .._camera import Camera
from .._errors import CaptureError
from .._geometry import normals_from_depth
from .._units import METRIC, unit_of_reconstruction
from ._atomic import atomic_write_json, atomic_write_npy
from ._camera_json import AUTO_CEILINGS, read_camera, read_ceilings, read_encoding, read_stereo
from ._channel_ceiling import (
    ChannelKnee,
    ceiling_levels,
    channel_knees,
    knee_note,
    samples_of,
    saturation_of,
)
from ._desaturated import desaturated
from ._encoding import LINEAR, SRGB, decode, default_encoding, encode
from ._excluded import always_excluded, check_excluded_names, excluded_path, read_excluded
from ._field_of_view import visible_masks
from ._images import IMAGE_SUFFIXES, read_recorded, write_rgb
from ._stereo import RIGHT, StereoRig, right_image_path

# Normals further than this from unit length are rejected (float32 files are ~1e-7 off).
_UNIT_TOLERANCE = 1e-3


@dataclasses.dataclass(frozen=True)
class Frame:
    """One image of a capture and its optional geometry (NumPy arrays, camera frame)."""

    name: str
    image: np.ndarray  # float32 (H, W, 3), linear (decoded), [0, 1]
    depth: np.ndarray | None = None  # float32 (H, W), mm, NaN where unknown
    normals: np.ndarray | None = None  # float32 (H, W, 3), unit, facing the camera
    pose: np.ndarray | None = None  # float64 (4, 4), camera-to-world
    # bool (H, W): the scene, inside the endoscope's field of view, off overlays (see
    # `ctjax.io.field_of_view`) and off the pixels the capture excludes (instruments:
    # `ctjax.io._excluded`); None: everything is.
    field_of_view: np.ndarray | None = None

    @property
    def has_geometry(self) -> bool:
        return self.normals is not None

    @property
    def visible(self) -> np.ndarray:
        """(H, W) bool: the pixels of the scene (`field_of_view`, all when None)."""
        if self.field_of_view is None:
            return np.ones(self.image.shape[:2], bool)
        return self.field_of_view

    @property
    def geometry_mask(self) -> np.ndarray:
        """Pixels of the scene with a finite normal and (where depth is known) a finite
        positive depth (a new array: the caller may change it)."""
        return self._geometry_mask.copy()

    @functools.cached_property
    def _geometry_mask(self) -> np.ndarray:
        # Computed once per frame (the estimators read it many times); frames are frozen.
        if self.normals is None:
            return np.zeros(self.image.shape[:2], bool)
        mask = np.isfinite(self.normals[..., 0])
        for c in (1, 2):
            mask &= np.isfinite(self.normals[..., c])
        if self.depth is not None:
            mask &= np.isfinite(self.depth) & (self.depth > 0)
        if self.field_of_view is not None:
            mask &= self.field_of_view
        return mask


@dataclasses.dataclass(frozen=True)
class Capture:
    """A loaded capture: camera (undistorted), frames sorted by name, optional ground truth."""

    root: Path
    camera: Camera
    frames: tuple[Frame, ...]
    truth: dict | None = None
    # Of depth, poses and every length derived from them: "mm", or "median_depth" where the
    # shape was reconstructed without a known size (`ctjax._units`).
    length_unit: str = METRIC
    # How the image files encode light ("srgb" or "linear"); `Frame.image` is decoded.
    encoding: str = LINEAR
    # What the user should know about how the capture was read (one sentence each).
    notes: tuple[str, ...] = ()
    # A stereo laparoscope's right camera (camera.json's "stereo"; `ctjax.io._stereo`).
    stereo: StereoRig | None = None
    # Per channel, the level (decoded, as `Frame.image`) from which a value reads as clipped:
    # 1.0, or below it where the channel stops following the others or at the camera's white
    # below full scale (`ctjax.io._channel_ceiling`). The estimators' observations
    # (`ctjax._tracks`, the ring) leave out values at or above it, and S's rule reads them as
    # clipped; the images keep them, as recorded.
    saturation: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # The code values of the recorded images those levels come from (None: full scale), as
    # camera.json's "ceilings" takes them: what `reconstruct` keeps in reconstruction.json.
    ceilings: tuple[int | None, int | None, int | None] = (None, None, None)
    # The channels a camera's knee compressed, found on the frames (`channel_knees`).
    knees: tuple[ChannelKnee, ...] = ()

    def right_image(self, name: str) -> np.ndarray | None:
        """Frame `name`'s right image as recorded (encoded, float in [0, 1], the right
        camera's own grid, not undistorted), None where the capture has none; near-white
        the camera turned grey reads as clipped (1.0), as in the left frames."""
        path = right_image_path(self.root, name) if self.stereo is not None else None
        if path is None:
            return None
        raw = read_recorded(path)
        right = self.stereo.right
        if raw.shape[:2] != (right.height, right.width):  # every user of it needs this
            raise CaptureError(
                f"{path}: the right image of {name} is {raw.shape[1]}x{raw.shape[0]}, the "
                f"stereo camera (camera.json's stereo.right) says {right.width}x{right.height}"
            )
        top = 255.0 if raw.dtype == np.uint8 else 65535.0
        image = raw.astype(np.float32) / top
        image[desaturated(raw)] = 1.0
        return image

    @functools.cached_property
    def right_saturation(self) -> tuple[float, float, float]:
        """`saturation` of a stereo capture's right camera, found on its own images (its
        channels' ceilings, `ctjax.io._channel_ceiling`); full scale without a right camera."""
        declared = read_ceilings(self.root / "camera.json")
        if self.stereo is None or declared != AUTO_CEILINGS:  # given: the left camera's
            return self.saturation if self.stereo is not None else (1.0, 1.0, 1.0)
        samples = []
        for frame in self.frames:
            path = right_image_path(self.root, frame.name)
            if path is not None:
                raw = read_recorded(path)
                samples.append(samples_of(raw, desaturated(raw)))
        return ceiling_levels(samples, self.encoding)[0] if samples else (1.0, 1.0, 1.0)

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def has_geometry(self) -> bool:
        return all(frame.has_geometry for frame in self.frames)


# Above this share of a frame's normals facing away from the camera, the capture notes it.
FACING_AWAY_NOTED = 0.05


def _load_npy(path: Path, shape: tuple[int, ...], what: str) -> np.ndarray:
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as error:
        raise CaptureError(f"{path}: cannot read {what} ({error})") from None
    if array.shape != shape:
        raise CaptureError(f"{path}: {what} has shape {array.shape}, expected {shape}")
    if not np.issubdtype(array.dtype, np.floating):
        raise CaptureError(f"{path}: {what} must be floating point, got {array.dtype}")
    return array.astype(np.float32)


def _facing_away(camera: Camera, normals: np.ndarray) -> float:
    """The share of the finite normals that point away from the camera (N . ray > 0)."""
    h, w = normals.shape[:2]
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    ray = np.stack(
        [(u - float(camera.cx)) / float(camera.fx), (v - float(camera.cy)) / float(camera.fy)],
        axis=-1,
    )
    facing = normals[..., 0] * ray[..., 0] + normals[..., 1] * ray[..., 1] + normals[..., 2]
    finite = np.isfinite(facing)
    return float(np.mean(facing[finite] > 0)) if finite.any() else 0.0


def _read_poses(path: Path) -> dict[str, np.ndarray]:
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise CaptureError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(data, dict):
        raise CaptureError(f"{path}: expected {{NAME: 4x4 camera-to-world matrix}}")
    poses = {}
    for name, matrix in data.items():
        try:
            pose = np.asarray(matrix, dtype=np.float64)
        except (ValueError, TypeError):
            raise CaptureError(f"{path}: pose of {name!r} is not a 4x4 numeric matrix") from None
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise CaptureError(f"{path}: pose of {name!r} must be a finite 4x4 matrix")
        problem = _not_rigid(pose)
        if problem:
            raise CaptureError(f"{path}: the pose of {name!r} is not a rigid transform ({problem})")
        poses[name] = pose
    return poses


# A pose written as float32, or by another tool, is rigid to about 1e-6; a scale, a shear or
# a projective last row is off by far more and would give silently wrong views.
_ROTATION_TOLERANCE = 1e-3
_LAST_ROW_TOLERANCE = 1e-6


def _not_rigid(pose: np.ndarray) -> str | None:
    """Why a 4x4 camera-to-world matrix is no rotation and translation; None if it is."""
    last = pose[3]
    if np.max(np.abs(last - [0.0, 0.0, 0.0, 1.0])) > _LAST_ROW_TOLERANCE:
        return f"its last row is {np.round(last, 6).tolist()}, not [0, 0, 0, 1]"
    rotation = pose[:3, :3]
    off = float(np.max(np.abs(rotation.T @ rotation - np.eye(3))))
    if off > _ROTATION_TOLERANCE:
        return f"its 3x3 part is not a rotation, R^T R is off I by {off:.3g}: a scale or a shear"
    if np.linalg.det(rotation) <= 0:
        return "its 3x3 part has determinant -1: a reflection, not a rotation"
    return None


def _undistort(camera: Camera, frame: Frame) -> Frame:
    """Remap a frame of a distorted camera onto the ideal pinhole grid of the same K."""
    k = np.asarray(camera.intrinsic_matrix, np.float64)
    dist = np.asarray(camera.distortion, np.float64)
    size = (camera.width, camera.height)
    map_x, map_y = cv2.initUndistortRectifyMap(k, dist, None, k, size, cv2.CV_32FC1)

    def remap(a, interpolation, outside=np.nan):
        if a is None:
            return None
        out = cv2.remap(
            a,
            map_x,
            map_y,
            interpolation,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=outside,
        )
        return out

    scene = frame.field_of_view  # the pixels not excluded, on the recorded grid
    if scene is not None:
        scene = remap(scene.astype(np.uint8), cv2.INTER_NEAREST, 0).astype(bool)
    return dataclasses.replace(
        frame,
        image=remap(frame.image, cv2.INTER_LINEAR, 0),
        depth=remap(frame.depth, cv2.INTER_NEAREST),
        normals=remap(frame.normals, cv2.INTER_NEAREST),
        field_of_view=scene,
    )


def load_capture(
    path: str | Path,
    *,
    undistort: bool = True,
    field_of_view: bool = True,
    reconstructed_ceilings: bool = True,
) -> Capture:
    """Load a capture folder (see the module docstring for the format).

    Rejects bad input with one `CaptureError` naming the file: missing folder, missing or
    malformed camera.json (a principal point off the image, distortion keys other than
    k1 k2 p1 p2 k3 k4 k5 k6 that are not zero), unreadable image, sizes that disagree, normals that
    are not unit or that face away from the camera, poses that are not rigid.
    Normals are derived from depth where only depth is given. With distortion coefficients
    in camera.json and `undistort=True`, images (and depth/normals) are undistorted and the
    returned camera has none. With `field_of_view=True`, each frame's `field_of_view` marks
    the scene: the pixels inside the endoscope's image circle or polygon and off overlays
    constant over the video (`ctjax.io.visible_masks`); None where that is every pixel.
    Pixels `excluded/NAME.png` marks (instruments: `ctjax.io._excluded`), or `excluded.png`
    in every frame, are never in it. The channels' ceilings (`Capture.saturation`) are
    camera.json's where it gives them, else those `ctjax reconstruct` found on every frame it
    read (reconstruction.json's `ceilings`, with `reconstructed_ceilings`: a subset of a
    reconstructed capture's frames reads its values as the whole did), else found on these
    frames.
    """
    root = Path(path)
    if not root.exists():
        raise CaptureError(f"{root}: capture folder not found")
    if not root.is_dir():
        raise CaptureError(f"{root}: not a folder (a capture is a folder with camera.json)")
    camera = read_camera(root / "camera.json")
    image_dir = root / "images"
    if not image_dir.is_dir():
        raise CaptureError(f"{image_dir}: images folder not found")
    image_paths = sorted(p for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not image_paths:
        raise CaptureError(f"{image_dir}: no images ({', '.join(IMAGE_SUFFIXES)}) in the capture")
    twice = sorted(stem for stem, n in Counter(p.stem for p in image_paths).items() if n > 1)
    if twice:  # two files of one frame (frame_001.png and .jpg): which one is the frame?
        files = [p.name for p in image_paths if p.stem == twice[0]]
        raise CaptureError(
            f"{image_dir}: frame {twice[0]} has {len(files)} images ({', '.join(files)}): keep one"
        )
    poses = _read_poses(root / "poses.json") if (root / "poses.json").is_file() else {}
    size = (camera.height, camera.width)
    declared = read_encoding(root / "camera.json")
    encodings, frames, facing_notes, greyed, samples = set(), [], [], 0, []
    everywhere = always_excluded(root, size)
    for image_path in image_paths:
        name = image_path.stem
        raw = read_recorded(image_path)
        encodings.add(declared or default_encoding(8 if raw.dtype == np.uint8 else 16))
        if len(encodings) > 1:
            raise CaptureError(
                f"{image_dir}: 8- and 16-bit images mixed and camera.json does not say how they "
                'are encoded: add "encoding": "srgb" or "linear" to it'
            )
        image = decode(raw, next(iter(encodings)))
        grey = desaturated(raw)
        image[grey] = 1.0  # what the camera turned grey near its white reads as clipped
        greyed += int(grey.sum())
        samples.append(samples_of(raw, grey))
        if image.shape[:2] != size:
            raise CaptureError(
                f"{image_path}: image is {image.shape[1]}x{image.shape[0]}, camera.json says "
                f"{camera.width}x{camera.height}"
            )
        depth = normals = None
        depth_path = root / "depth" / f"{name}.npy"
        if depth_path.is_file():
            depth = _load_npy(depth_path, size, "depth")
            if not np.any(np.isfinite(depth) & (depth > 0)):
                raise CaptureError(f"{depth_path}: no finite positive depth in the whole map")
        normals_path = root / "normals" / f"{name}.npy"
        if normals_path.is_file():
            normals = _load_npy(normals_path, (*size, 3), "normals")
            norm = np.linalg.norm(normals, axis=-1)
            finite = np.isfinite(norm)
            if np.any(np.abs(norm[finite] - 1) > _UNIT_TOLERANCE):
                raise CaptureError(f"{normals_path}: normals are not unit vectors")
            away = _facing_away(camera, normals)
            if away > 0.5:
                raise CaptureError(
                    f"{normals_path}: normals face away from the camera (they must point "
                    "towards it: flip their sign)"
                )
            if away > FACING_AWAY_NOTED:  # a surface seen from behind: those pixels unused
                facing_notes.append(f"{normals_path}: {away:.0%} of the normals face away")
        elif depth is not None:
            normals = normals_from_depth(camera, depth)
        excluded = excluded_path(root, name)
        scene = None if excluded is None else ~read_excluded(excluded, size)
        if everywhere is not None:
            scene = ~everywhere if scene is None else scene & ~everywhere
        frames.append(Frame(name, image, depth, normals, poses.get(name), scene))
    check_excluded_names(root, {frame.name for frame in frames})
    truth = None
    if (root / "truth.json").is_file():
        try:
            truth = json.loads((root / "truth.json").read_text())
        except json.JSONDecodeError as error:
            raise CaptureError(f"{root / 'truth.json'}: not valid JSON ({error})") from None
    _refuse_duplicates(root, frames)
    unit = METRIC
    declared_ceilings, source = read_ceilings(root / "camera.json"), "camera.json's ceilings"
    if (root / "reconstruction.json").is_file():
        try:
            unit = unit_of_reconstruction(json.loads((root / "reconstruction.json").read_text()))
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
            raise CaptureError(
                f"{root / 'reconstruction.json'}: not a reconstruction report"
            ) from None
        if declared_ceilings == AUTO_CEILINGS and reconstructed_ceilings:
            declared_ceilings = read_ceilings(root / "reconstruction.json")
            source = "reconstruction.json's ceilings, found on every frame ctjax reconstruct read"
    encoding = encodings.pop()
    notes = ()
    if declared is None and encoding == SRGB:
        notes = (
            f"{root / 'camera.json'} does not say how its images are encoded: 8-bit frames are "
            'decoded as sRGB (as video and JPEG frames are); add "encoding": "linear" to it if '
            'they are linear, or "encoding": "srgb" to silence this note',
        )
    if greyed:
        share = greyed / (len(frames) * size[0] * size[1])
        notes = (
            *notes,
            f"{share:.2%} of the frames' pixels are near-white that the camera turned grey (its "
            "channels within one code value, in frames of coloured tissue): read as clipped",
        )
    saturation, ceilings, said = saturation_of(frames, samples, encoding, declared_ceilings, source)
    knees = channel_knees(samples)
    notes = (*notes, *filter(None, (said, knee_note(knees))))
    if facing_notes:
        notes = (
            *notes,
            "; ".join(facing_notes[:3])
            + (f" (and {len(facing_notes) - 3} more frames)" if len(facing_notes) > 3 else "")
            + " from the camera: a surface seen from behind, those pixels are not used (normals "
            "with a wrong sign in places?)",
        )
    if undistort and camera.distortion is not None:
        frames = [_undistort(camera, frame) for frame in frames]
        camera = camera.without_distortion()
    if field_of_view:
        frames = _with_field_of_view(frames, encoding)
    stereo = read_stereo(root / "camera.json")
    if stereo is not None:
        absent = [f.name for f in frames if right_image_path(root, f.name) is None]
        if absent:
            raise CaptureError(
                f"{root / RIGHT}: camera.json describes a stereo camera but the right image of "
                f"{', '.join(absent[:3])}{' ...' if len(absent) > 3 else ''} is missing"
            )
        if not BASELINE_MM[0] <= stereo.baseline_mm <= BASELINE_MM[1]:
            notes = (*notes, unlikely_baseline(root, stereo.baseline_mm))
    return Capture(
        root,
        camera,
        tuple(frames),
        truth,
        unit,
        encoding,
        notes,
        stereo,
        saturation,
        ceilings,
        knees,
    )


# A stereo endoscope's baseline (mm): a da Vinci's 4-5.5, the smallest 3D scopes' about 2.
BASELINE_MM = (1.0, 30.0)


def unlikely_baseline(root: Path, baseline: float) -> str:
    return (
        f"{root / 'camera.json'}: stereo.T is {baseline:.3g} mm long, outside the "
        f"{BASELINE_MM[0]:g}-{BASELINE_MM[1]:g} mm of a stereo endoscope's baseline (a da "
        "Vinci's is 4-5.5 mm): T is in millimetres (X_right = R X_left + T; metres give depths "
        "a thousand times too small)"
    )


# Frames whose images differ by at most this much (recorded units) everywhere are the same
# view recorded twice: half an 8-bit level.
_DUPLICATE_LEVEL = 0.5 / 255


def _refuse_duplicates(root: Path, frames: list[Frame]) -> None:
    """One `CaptureError` naming the frames that repeat an earlier one: a repeated view
    adds no parallax for structure-from-motion and no new angle for the fits, and
    pretends to be independent evidence in a held-out split."""
    thumbnails = [cv2.resize(f.image, (32, 32), interpolation=cv2.INTER_AREA) for f in frames]
    repeats = []
    for j in range(1, len(frames)):
        for i in range(j):
            if np.max(np.abs(thumbnails[i] - thumbnails[j])) > _DUPLICATE_LEVEL:
                continue
            if np.max(np.abs(frames[i].image - frames[j].image)) <= _DUPLICATE_LEVEL:
                repeats.append(f"{frames[j].name} = {frames[i].name}")
                break
    if repeats:
        raise CaptureError(
            f"{root}: duplicate frames (identical images): {', '.join(repeats[:5])}"
            + (f" and {len(repeats) - 5} more" if len(repeats) > 5 else "")
            + "; remove the repeats (a still camera adds no view; ctjax import drops them)"
        )


def _with_field_of_view(frames: list[Frame], encoding: str) -> list[Frame]:
    """`frames` with their `field_of_view` (None where every pixel is of the scene), found
    on the recorded values (the border's and overlays' levels are of the video's), within
    the one they have (the pixels not excluded)."""
    masks = visible_masks([encode(frame.image, encoding) for frame in frames])
    masks = [
        mask if frame.field_of_view is None else mask & frame.field_of_view
        for frame, mask in zip(frames, masks, strict=True)
    ]
    return [
        dataclasses.replace(frame, field_of_view=None if mask.all() else mask)
        for frame, mask in zip(frames, masks, strict=True)
    ]


def write_capture(
    path: str | Path,
    camera: Camera,
    frames: list[Frame] | tuple[Frame, ...],
    truth: dict | None = None,
    *,
    bits: int = 8,
    encoding: str = LINEAR,
    stereo: StereoRig | None = None,
    right: dict | None = None,
) -> Path:
    """Write frames in the capture format (atomically, file by file). Returns the folder.

    Images are linear float RGB in [0, 1], clipped, encoded with `encoding` ("linear" or
    "srgb", recorded in camera.json) and quantised to `bits` (8 or 16). A stereo capture:
    `stereo` (camera.json's "stereo") and `right` {NAME: the right camera's linear image}.
    """
    root = Path(path)
    _refuse_other_frames(root, {frame.name for frame in frames})
    root.mkdir(parents=True, exist_ok=True)
    described = {**camera.to_json(), "encoding": encoding}
    if stereo is not None:
        described["stereo"] = stereo.to_json()
    atomic_write_json(root / "camera.json", described)
    for name, image in (right or {}).items():
        write_rgb(root / RIGHT / f"{name}.png", image, bits=bits, encoding=encoding)
    poses = {}
    for frame in frames:
        path = root / "images" / f"{frame.name}.png"
        write_rgb(path, frame.image, bits=bits, encoding=encoding)
        if frame.depth is not None:
            atomic_write_npy(root / "depth" / f"{frame.name}.npy", frame.depth.astype(np.float32))
        if frame.normals is not None:
            normals = frame.normals.astype(np.float32)
            atomic_write_npy(root / "normals" / f"{frame.name}.npy", normals)
        if frame.pose is not None:
            poses[frame.name] = np.asarray(frame.pose, np.float64).tolist()
    if poses:
        atomic_write_json(root / "poses.json", poses)
    if truth is not None:
        atomic_write_json(root / "truth.json", truth)
    return root


def _refuse_other_frames(root: Path, names: set[str]) -> None:
    """A folder holding images of other frames would become a capture mixing two (its stale
    frames loaded beside the new ones): refused, naming them. The same frames are replaced."""
    for folder in (root / "images", root / RIGHT):
        if not folder.is_dir():
            continue
        others = sorted(p.name for p in folder.iterdir() if p.is_file() and p.stem not in names)
        if others:
            shown = ", ".join(others[:3]) + (
                f" and {len(others) - 3} more" if len(others) > 3 else ""
            )
            raise CaptureError(
                f"{folder}: holds images of other frames ({shown}); write the capture into an "
                "empty folder (or remove them)"
            )
