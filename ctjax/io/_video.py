"""`ctjax import`: a capture from an endoscopic video (any format OpenCV reads, or a folder
of images: `ctjax.io._frame_source`).

Frames are chosen in two passes over the video, so that only small thumbnails are held:

1. Each considered frame (every `every`-th between `start` and `end` seconds) is reduced to
   a grey thumbnail `THUMBNAIL_WIDTH` px wide, inside the endoscope's field of view of the
   first frame (`field_of_view`), and its sharpness is measured: the variance of the
   Laplacian of the thumbnail (Pech-Pacheco et al. 2000), which motion blur lowers.
2. Motion-blurred frames are dropped: sharpness below `blur_ratio` times the median
   sharpness of the `BLUR_WINDOW` considered frames around it (relative, so a smooth
   scene is not called blurred).
3. The rest are grouped into runs of near-duplicates: a run ends where a frame differs from
   the run's first frame by at least `distinct` (mean absolute difference of the blurred
   thumbnails over the field of view, relative to their mean brightness). A still camera
   makes one run; each run keeps its sharpest frame.
4. More than `max_frames` left: that many, evenly spread in time.

The second pass decodes the video again and writes the kept frames as
`CAPTURE/images/frame_NNNNNN.png` (the video's frame number, zero-padded: names sort in
time) with `camera.json` copied beside them, marked `"encoding": "srgb"` (unless the
endoscope's camera.json says otherwise: video frames are encoded). The calibration may be
camera.json or OpenCV's file (`ctjax.io._opencv_calibration`). A stereo video: a second
file frame for frame, or each frame holding both images (side by side, or the left above
the right); the right images go to `CAPTURE/right/`. Masks of what is not tissue
(instruments), a video or folder frame for frame with the video, go to `CAPTURE/excluded/`
(`ctjax.io._excluded`).
"""

import dataclasses
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from .._errors import CaptureError, ParameterError
from ._atomic import atomic_write_json
from ._camera_json import camera_from_json, read_camera, read_encoding, read_stereo
from ._davinci_calibration import camera_json_from_davinci, is_davinci_calibration
from ._encoding import SRGB
from ._excluded import EXCLUDED
from ._field_of_view import field_of_view
from ._frame_source import frame_size, frames, image_files, rate_and_count, read_frame
from ._images import IMAGE_SUFFIXES, write_mask, write_quantised_rgb
from ._opencv_calibration import RIGHT_MATRIX, camera_json_from_opencv, is_opencv_calibration
from ._stereo import RIGHT, parse_stereo

THUMBNAIL_WIDTH = 320
BLUR_WINDOW = 31


@dataclasses.dataclass(frozen=True)
class ImportOptions:
    """Which frames of a video become a capture (see the module doc)."""

    every: int = 1  # consider every this-many-th frame
    start: float = 0.0  # seconds
    end: float | None = None  # seconds (None: to the end)
    max_frames: int | None = None
    distinct: float = 0.03  # a new view: thumbnails differ by this, relative
    blur_ratio: float = 0.5  # blurred: sharpness below this times its neighbours' median
    width: int | None = None  # write the frames this wide (area-averaged), K scaled
    # A stereo video recorded side by side: each frame's left half is the left camera's,
    # its right half the right camera's.
    side_by_side: bool = False
    # Or one above the other: each frame's top half is the left camera's, its bottom half
    # the right camera's (SCARED's rgb.mp4: 1280x2048 frames of two 1280x1024 images).
    top_bottom: bool = False

    def __post_init__(self):
        if int(self.every) != self.every or self.every < 1:
            raise ParameterError(f"--every must be a positive integer, got {self.every}")
        if not np.isfinite(self.start) or self.start < 0:
            raise ParameterError(
                f"--start must be a non-negative time in seconds, got {self.start}"
            )
        if self.end is not None and not (np.isfinite(self.end) and self.end > self.start):
            raise ParameterError(f"--end must be a time after --start, got {self.end}")
        if self.max_frames is not None and (
            int(self.max_frames) != self.max_frames or self.max_frames < 2
        ):
            raise ParameterError(f"--max-frames must be an integer >= 2, got {self.max_frames}")
        if not 0 < self.distinct < 1:
            raise ParameterError(f"--distinct must be in (0, 1), got {self.distinct}")
        if not 0 <= self.blur_ratio < 1:
            raise ParameterError(f"blur_ratio must be in [0, 1), got {self.blur_ratio}")
        if self.width is not None and (int(self.width) != self.width or self.width < 16):
            raise ParameterError(f"--width must be an integer >= 16, got {self.width}")
        if self.side_by_side and self.top_bottom:
            raise ParameterError("a stereo video is --side-by-side or --top-bottom, not both")

    @property
    def stacked(self) -> bool:
        """Whether each frame holds both cameras' images (side by side or one above the
        other)."""
        return self.side_by_side or self.top_bottom


@dataclasses.dataclass(frozen=True)
class _Scan:
    indices: np.ndarray  # video frame numbers considered
    thumbnails: list[np.ndarray]  # grey, blurred, float32
    sharpness: np.ndarray
    size: tuple[int, int]  # (width, height)
    fps: float
    fov: np.ndarray  # the first frame's field of view, at the thumbnails' size


# A video without a calibration (`ctjax import --camera guess`): a pinhole camera with this
# focal length in widths (fx = fy), the principal point at the centre, no distortion.
GUESSED_FOCAL = 0.8


def camera_size(path: Path, options: ImportOptions = ImportOptions()) -> tuple[int, int]:
    """One camera's image size in the video's frames, (width, height): the left half's (or
    the top half's) where each frame holds both cameras' (`options`)."""
    width, height = frame_size(Path(path))
    return width // (2 if options.side_by_side else 1), height // (2 if options.top_bottom else 1)


def guessed_camera(path: Path, side_by_side: bool = False, top_bottom: bool = False) -> dict:
    """camera.json's content for a video without a calibration: its frame size (one
    camera's, for a stereo video whose frames hold both), fx = fy = `GUESSED_FOCAL` width,
    the principal point at the centre. The focal length is a guess: `ctjax reconstruct
    --focal refine` refines it from the frames where they determine it."""
    layout = ImportOptions(side_by_side=side_by_side, top_bottom=top_bottom)
    width, height = camera_size(path, layout)
    focal = GUESSED_FOCAL * width
    return {
        "width": width,
        "height": height,
        "fx": focal,
        "fy": focal,
        "cx": (width - 1) / 2,
        "cy": (height - 1) / 2,
        "encoding": "srgb",
    }


def _frames(path: Path, options: ImportOptions, fps: float):
    """(frame number, BGR uint8 image) of the considered frames, decoding only those."""
    last = None if options.end is None else round(options.end * fps)
    return frames(path, round(options.start * fps), last, options.every)


def _halves(image: np.ndarray, options: ImportOptions) -> tuple[np.ndarray, np.ndarray | None]:
    """The left camera's image and the right one's in a frame that holds both (side by
    side, or the left above the right), else the frame itself and None."""
    if options.side_by_side:
        half = image.shape[1] // 2
        return image[:, :half], image[:, half : 2 * half]
    if options.top_bottom:
        half = image.shape[0] // 2
        return image[:half], image[half : 2 * half]
    return image, None


def _small(image: np.ndarray) -> np.ndarray:
    """A BGR frame as RGB, `THUMBNAIL_WIDTH` px wide."""
    height, width = image.shape[:2]
    size = (THUMBNAIL_WIDTH, max(1, round(height * THUMBNAIL_WIDTH / width)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)[..., ::-1]


def _thumbnail(image: np.ndarray, fov: np.ndarray) -> tuple[np.ndarray, float]:
    """The grey thumbnail (blurred against compression noise) and its sharpness."""
    grey = cv2.cvtColor(np.ascontiguousarray(_small(image)), cv2.COLOR_RGB2GRAY)
    grey = grey.astype(np.float32) / 255
    laplacian = cv2.Laplacian(grey, cv2.CV_32F)
    sharpness = float(np.var(laplacian[fov])) if fov.any() else 0.0
    return cv2.GaussianBlur(grey, (0, 0), 1.5), sharpness


def _scan(path: Path, options: ImportOptions, progress: Callable[[str], None]) -> _Scan:
    fps, total = rate_and_count(path)
    indices, thumbnails, sharpness = [], [], []
    fov = size = None
    for index, image in _frames(path, options, fps):
        image = _halves(image, options)[0]
        if fov is None or not fov.any():  # from the first frame that shows something
            size = (image.shape[1], image.shape[0])
            fov = field_of_view(_small(image).astype(np.float32) / 255)
        thumbnail, sharp = _thumbnail(image, fov)
        indices.append(index)
        thumbnails.append(thumbnail)
        sharpness.append(sharp)
        if len(indices) % 100 == 0:
            progress(f"scanned {index + 1}" + (f"/{total}" if total else "") + " frames")
    if not indices:
        raise CaptureError(f"{path}: no frame between --start and --end (the video has {total})")
    if not fov.any():  # the frames before the first that shows something have sharpness 0
        raise CaptureError(
            f"{path}: no frame between --start and --end shows anything (black, or all "
            "border): nothing to import"
        )
    return _Scan(np.array(indices), thumbnails, np.array(sharpness), size, fps, fov)


def select_frames(scan: _Scan, options: ImportOptions) -> tuple[list[int], dict]:
    """The kept frames' positions in `scan`, and the counts of those dropped and why."""
    n, fov = len(scan.indices), scan.fov
    half = BLUR_WINDOW // 2
    around = [np.median(scan.sharpness[max(0, i - half) : i + half + 1]) for i in range(n)]
    sharp = scan.sharpness >= options.blur_ratio * np.array(around)
    runs: list[list[int]] = []
    for i in np.flatnonzero(sharp):
        if runs:
            first = scan.thumbnails[runs[-1][0]]
            level = max(float(np.mean(first[fov])), 1e-3)
            if np.mean(np.abs(scan.thumbnails[i][fov] - first[fov])) < options.distinct * level:
                runs[-1].append(i)
                continue
        runs.append([i])
    kept = [max(run, key=lambda i: scan.sharpness[i]) for run in runs]
    spread = 0
    if options.max_frames is not None and len(kept) > options.max_frames:
        chosen = np.unique(np.round(np.linspace(0, len(kept) - 1, options.max_frames)).astype(int))
        spread = len(kept) - len(chosen)
        kept = [kept[i] for i in chosen]
    counts = {
        "considered": n,
        "blurred": int(n - sharp.sum()),
        "near_duplicates": int(sharp.sum() - len(runs)),
        "over_max_frames": spread,
        "kept": len(kept),
    }
    return kept, counts


def _scaled(camera, width: int | None):
    """`camera` for frames `width` px wide (pixel centres kept: c' = (c + 0.5) s - 0.5),
    and the new (width, height); None where the frames keep their size."""
    if width is None or width == camera.width:
        return camera, None
    scale = width / camera.width
    height = max(1, round(camera.height * scale))
    scaled = type(camera)(
        width,
        height,
        float(camera.fx) * scale,
        float(camera.fy) * scale,
        (float(camera.cx) + 0.5) * scale - 0.5,
        (float(camera.cy) + 0.5) * scale - 0.5,
        distortion=camera.distortion,  # radial and tangential terms are in normalised units
    )
    return scaled, (width, height)


def _described(name: str, fps: float, files: list[Path] | None) -> dict:
    """A kept frame in the report: its name, its time and, from a folder, its file."""
    index = int(name.split("_")[1])
    return {"name": name, "time_s": index / fps} | (
        {} if files is None else {"source": files[index].name}
    )


def _stacked_layout(camera, width: int, height: int) -> str | None:
    """The stereo layout that frames `width` x `height` px with `camera`'s principal point
    suggest, where one is clear (much wider or taller than a camera's image, the principal
    point at a half's centre); None otherwise."""
    if height > width and abs(camera.cy - height / 4) < 0.1 * height:
        return "--top-bottom"
    if width > 2.2 * height and abs(camera.cx - width / 4) < 0.1 * width:
        return "--side-by-side"
    return None


def _excluded_mask(mask: np.ndarray, recorded: tuple[int, int], size, source: Path) -> np.ndarray:
    """A mask frame (BGR uint8) of a camera's image `recorded` (width, height) px as the
    excluded pixels of the frame written at `size` (None: as recorded): above half scale
    in any channel (a compressed mask video's black is not exactly 0), and, shrunk, every
    new pixel that holds any of them."""
    if (mask.shape[1], mask.shape[0]) != recorded:
        raise CaptureError(
            f"{source}: mask frames are {mask.shape[1]}x{mask.shape[0]}, the camera's images "
            f"{recorded[0]}x{recorded[1]}"
        )
    excluded = np.any(mask > 127, axis=-1)
    if size is not None:
        shrunk = cv2.resize(excluded.astype(np.uint8) * 255, size, interpolation=cv2.INTER_AREA)
        excluded = shrunk > 0
    return excluded


def _check_pairs(left: Path, right: Path) -> None:
    """Two folders pair their files in name order: they must hold as many, and where they
    share names, the same names in the same places (a file missing on one side would
    otherwise pair every later view with its neighbour's)."""
    lefts, rights = image_files(left), image_files(right)
    if lefts is None or rights is None:
        return
    if len(lefts) != len(rights):
        raise CaptureError(
            f"{right}: {len(rights)} images where {left} has {len(lefts)}: a stereo pair's "
            "folders hold one image per instant each"
        )
    left_names, right_names = [p.stem for p in lefts], [p.stem for p in rights]
    if set(left_names) & set(right_names) and left_names != right_names:
        first = next(a for a, b in zip(left_names, right_names, strict=True) if a != b)
        raise CaptureError(
            f"{right}: its images are not named as {left}'s (first apart: {first}): each "
            "right image pairs with the left one of the same place in name order"
        )


def _calibration(camera_path: Path, video: Path, options: ImportOptions, stereo: bool):
    """The left camera, the stereo rig (None for a single camera) and the declared encoding
    (None: not said) from camera.json, an OpenCV calibration file or a da Vinci's."""
    if is_opencv_calibration(camera_path) or is_davinci_calibration(camera_path):
        size = camera_size(video, options)
        davinci = is_davinci_calibration(camera_path)
        reader = camera_json_from_davinci if davinci else camera_json_from_opencv
        described = reader(camera_path, *size)
        intrinsics = camera_from_json(described, camera_path)
        layout = None if options.stacked else _stacked_layout(intrinsics, *size)
        if layout is not None:
            raise CaptureError(
                f"{video}: its {size[0]}x{size[1]} frames look like two cameras' images "
                f"({layout}: the principal point ({intrinsics.cx:.0f}, {intrinsics.cy:.0f}) "
                f"is the centre of one half); give {layout}, or a video of one camera"
            )
        rig = None
        if stereo and "stereo" in described:
            rig = parse_stereo(described["stereo"], intrinsics, str(camera_path), camera_from_json)
        if stereo and rig is None:
            raise CaptureError(
                f"{camera_path}: a stereo import needs the right camera's matrix (one of "
                f"{', '.join(RIGHT_MATRIX)}) with R and T; the file has the left camera's only"
            )
        return intrinsics, rig, None
    intrinsics = read_camera(camera_path)
    rig = read_stereo(camera_path) if stereo else None
    if stereo and rig is None:
        raise CaptureError(
            f'{camera_path}: a stereo import needs camera.json\'s "stereo" block (the right '
            'camera\'s "right": {fx, fy, cx, cy}, "R" and "T" in mm, X_right = R X_left + T)'
        )
    return intrinsics, rig, read_encoding(camera_path)


def import_video(
    video: str | Path,
    camera: str | Path,
    out: str | Path,
    options: ImportOptions = ImportOptions(),
    *,
    right: str | Path | None = None,
    excluded: str | Path | None = None,
    right_excluded: str | Path | None = None,
    force: bool = False,
    progress: Callable[[str], None] = lambda message: None,
) -> dict:
    """Write a capture folder `out` from the distinct, sharp frames of `video` (see the
    module doc). `camera` is the camera.json of the endoscope (its size must be the
    video's). Returns a report: the counts of frames considered, dropped and kept, and the
    kept frames' names and times.

    `camera` may also be an OpenCV calibration file (`cv::FileStorage` YAML or XML, e.g.
    SCARED's `endoscope_calibration.yaml`: `ctjax.io._opencv_calibration`) or a da Vinci's
    `StereoCalibration.ini` (StereoMIS's: `ctjax.io._davinci_calibration`), for frames of
    the video's size; the capture's camera.json is written from it.

    A stereo laparoscope: `right`, the right camera's video (frame for frame with
    `video`), or `options.side_by_side` / `options.top_bottom` (each frame holds both);
    the calibration must then have the right camera (camera.json's `"stereo"` block,
    `ctjax.io._stereo`), and the capture gets `right/NAME.png` beside `images/NAME.png`.
    Frames are chosen on the left camera's.

    `excluded`: one image, the pixels excluded in every frame (written as `excluded.png`: an
    overlay the loader does not find), or a video or folder of masks, frame for frame with
    `video` (laid out as it:
    side by side or one above the other, both cameras'), white (above half scale) where a
    pixel is not tissue (a surgical instrument); written as `excluded/NAME.png`
    (`ctjax.io._excluded`: no command uses those pixels). `right_excluded`: the right
    video's, frame for frame with `right`."""
    video, camera_path, out = Path(video), Path(camera), Path(out)
    if right is not None and options.stacked:
        raise ParameterError("give a right video or --side-by-side / --top-bottom, not both")
    stereo = options.stacked or right is not None
    if right_excluded is not None and right is None:
        raise ParameterError("--right-excluded masks the right video: give --right too")
    everywhere = None  # one image: the pixels excluded in every frame (`excluded.png`)
    if excluded is not None and Path(excluded).suffix.lower() in IMAGE_SUFFIXES:
        mask_file = Path(excluded)
        everywhere, excluded = read_frame(mask_file), None
    # A folder without images: said before anything else.
    for source in (video, right, excluded, right_excluded):
        if source is not None:
            image_files(Path(source))
    if right is not None:
        _check_pairs(video, Path(right))
    intrinsics, rig, encoding = _calibration(camera_path, video, options, stereo)
    if options.width is not None and options.width > intrinsics.width:
        # Area averaging only shrinks: a wider frame would be interpolated, no new detail.
        raise ParameterError(
            f"--width {options.width} cannot exceed the video's width ({intrinsics.width} px): "
            "it only shrinks the frames"
        )
    images = out / "images"
    if images.is_dir() and any(images.iterdir()) and not force:
        raise CaptureError(f"{images}: already has images (--force replaces them)")
    scan = _scan(video, options, progress)
    if scan.size != (intrinsics.width, intrinsics.height):
        width, height = scan.size
        double = {
            (2 * intrinsics.width, intrinsics.height): "--side-by-side",
            (intrinsics.width, 2 * intrinsics.height): "--top-bottom",
        }.get(scan.size if not options.stacked else None)
        raise CaptureError(
            f"{video}: frames are {width}x{height}, {camera_path} says "
            f"{intrinsics.width}x{intrinsics.height}"
            + (f" (two cameras' images in each frame? {double})" if double else "")
        )
    kept, counts = select_frames(scan, options)
    progress(
        f"keeping {counts['kept']} of {counts['considered']} frames ({counts['blurred']} "
        f"blurred, {counts['near_duplicates']} near-duplicates"
        + (f", {counts['over_max_frames']} over --max-frames" if counts["over_max_frames"] else "")
        + ")"
    )
    if images.is_dir() and force:
        shutil.rmtree(images)
        for stale in (RIGHT, EXCLUDED):
            if (out / stale).is_dir():
                shutil.rmtree(out / stale)
        # The shape reconstructed from the replaced frames belongs to them, not to the new.
        for stale in ("depth", "normals"):
            if (out / stale).is_dir():
                shutil.rmtree(out / stale)
        for stale in ("poses.json", "reconstruction.json", f"{EXCLUDED}.png"):
            (out / stale).unlink(missing_ok=True)
    wanted = {int(scan.indices[i]) for i in kept}
    files = image_files(video)
    digits = max(6, len(str(max(wanted))))
    names = []
    intrinsics, size = _scaled(intrinsics, options.width)
    right_size = None
    recorded_right = None if rig is None else (rig.right.width, rig.right.height)
    if rig is not None and size is not None:
        scale = size[0] / rig.right.width if rig.right.width else 1.0
        rig = dataclasses.replace(rig, right=_scaled(rig.right, round(rig.right.width * scale))[0])
        right_size = (rig.right.width, rig.right.height)
    # The videos (or folders) read frame for frame with `video`.
    sources = {"right": right, "excluded": excluded, "right_excluded": right_excluded}
    beside = {
        key: _frames(Path(source), options, scan.fps)
        for key, source in sources.items()
        if source is not None
    }
    recorded = (scan.size, recorded_right)
    for index, image in _frames(video, options, scan.fps):
        image, other = _halves(image, options)
        read = {}
        for key, frames_beside in beside.items():
            other_index, read[key] = next(frames_beside, (None, None))
            if other_index != index:
                raise CaptureError(f"{sources[key]}: ends before {video} (frame {index})")
        other = read.get("right", other)
        masks = [None, None]  # the left camera's excluded pixels, the right one's
        if "excluded" in read:
            masks = list(_halves(read["excluded"], options))
        masks[1] = read.get("right_excluded", masks[1])
        if index not in wanted:
            continue
        name = f"frame_{index:0{digits}d}"
        if size is not None:
            # Averaging the recorded (encoded) values over each new pixel's area: the
            # error against averaging light is a fraction of a level on tissue.
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        write_quantised_rgb(images / f"{name}.png", image[..., ::-1])
        if rig is not None:
            if (other.shape[1], other.shape[0]) != recorded_right:
                raise CaptureError(
                    f"{right or video}: right frames are {other.shape[1]}x{other.shape[0]}, "
                    f"{camera_path}'s stereo.right says {recorded_right[0]}x{recorded_right[1]}"
                )
            if right_size is not None:
                other = cv2.resize(other, right_size, interpolation=cv2.INTER_AREA)
            write_quantised_rgb(out / RIGHT / f"{name}.png", np.ascontiguousarray(other[..., ::-1]))
        mask_sources = (excluded, right_excluded or excluded)
        for mask, camera, written, folder, source in zip(
            masks, recorded, (size, right_size), (EXCLUDED, f"{EXCLUDED}/right"), mask_sources,
            strict=True,
        ):  # fmt: skip
            if mask is not None and camera is not None:
                mask = _excluded_mask(mask, camera, written, Path(source))
                write_mask(out / folder / f"{name}.png", mask)
        names.append(name)
        progress(f"wrote {len(names)}/{len(wanted)} frames")
        if len(names) == len(wanted):
            break
    if everywhere is not None:  # as the left camera's images: its half of a stacked layout
        mask = _excluded_mask(_halves(everywhere, options)[0], scan.size, size, Path(mask_file))
        write_mask(out / f"{EXCLUDED}.png", mask)
    # Video frames are sRGB-encoded (every camera pipeline encodes before compression),
    # unless the endoscope's camera.json says otherwise.
    described = {**intrinsics.to_json(), "encoding": encoding or SRGB}
    if rig is not None:
        described["stereo"] = rig.to_json()
    atomic_write_json(out / "camera.json", described)
    return {
        "video": str(video),
        "out": str(out),
        "fps": scan.fps,
        **counts,
        "frames": [_described(n, scan.fps, files) for n in names],
        **({} if rig is None else {"baseline_mm": rig.baseline_mm}),
    }
