"""The specular set S on real endoscopic frames: does it cover the highlights, and only them?

    .venv/bin/python benchmarks/masks_real.py [CAPTURE ...] [--scales 1 3] [--every 1]
        [--video-frames 12] [--rule both|previous|default] [--per-frame] [--fov file|computed]

For each sequence of `../shared/real` (the sinus frames, 12 frames of the cholecystectomy
video; skipped with a message when absent) and each CAPTURE folder given (its `images/`,
read as files, decoded as camera.json's `"encoding"` says, sRGB by default), at full
resolution and at each `--scales` downscale (cv2.INTER_AREA on the recorded image, as a user
shrinks frames), one row per rule:

- cores: the near-white pixels a user sees, every channel >= 230 in the *recorded* 8-bit
  image, inside the field of view eroded by 15 px at full resolution (the bright rim of the
  image circle; 15 / scale px at a downscale);
- recall |S & cores| / |cores|, and S's area over that of the cores dilated by a 7x7 square
  (both in pixels of the image measured), summed over the frames of the sequence; the goal
  is recall >= 0.95 and ratio <= 3;
- S's share of the field of view, the frames whose own recall or ratio misses the goal,
  and the seconds per frame of the rule.

The rule sees *linear* values: the recorded frame decoded with the sRGB curve, as
`ctjax.io` does. "previous" is `WhiterThanTissue` as it was before the rule grew from seeds
(kept here for the comparison); "default" is the library's `DEFAULT_HIGHLIGHTS`. The field
of view: the sequence's `undistorted_mask.bmp` (white = inside) where there is one, else
`ctjax.io.visible_masks` of the recorded frames (what `ctjax masks` uses); `--fov computed`
always computes it. One JSON line per sequence, scale and rule (`_results.emit`).
"""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from _results import emit

from ctjax._tissue import SUBSAMPLE, channel_max, channel_min, local_tissue, luminance
from ctjax.estimation import specular_mask
from ctjax.io import visible_masks
from ctjax.specular._specular_set import DEFAULT_HIGHLIGHTS

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "real"
CORE_LEVEL = 230  # recorded 8-bit value of every channel of a near-white core
RIM_PX = 15  # the field of view's bright rim, at full resolution
DILATION = np.ones((7, 7), np.uint8)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclasses.dataclass(frozen=True)
class PreviousWhiterThanTissue:
    """`WhiterThanTissue` before it grew S from seeds: bright, near white, whiter and
    brighter than a local tissue median that every pale bright pixel was left out of (so a
    pale wall was compared with the red tissue beyond it), or clipped."""

    whiteness: float = 0.5
    near_white: float = 0.6
    contrast: float = 1.15
    clip_level: float = 0.98
    clip_chroma: float = 0.3
    window: float = 1 / 12

    def __call__(self, image, visible):
        if not visible.any():
            return np.zeros(visible.shape, bool)
        brightest, least = channel_max(image), channel_min(image)
        ratio = least / np.maximum(brightest, 1e-6)
        bright = brightest >= np.median(brightest[visible][::SUBSAMPLE])
        candidate = visible & bright & (ratio >= self.near_white)
        tissue = local_tissue(image, visible & ~candidate, self.window)
        tissue_ratio = np.minimum(channel_min(tissue) / np.maximum(channel_max(tissue), 1e-6), 0.95)
        whiter = (ratio - tissue_ratio) >= self.whiteness * (1 - tissue_ratio)
        brighter = luminance(image) >= self.contrast * luminance(tissue)
        white_clip = least >= self.clip_level
        tinted_clip = (brightest >= self.clip_level) & (ratio >= 1 - self.clip_chroma) & whiter
        return visible & (white_clip | tinted_clip | (candidate & whiter & brighter))


RULES = {"previous": PreviousWhiterThanTissue(), "default": DEFAULT_HIGHLIGHTS}


def decode(recorded: np.ndarray, encoding: str = "srgb") -> np.ndarray:
    """Linear float32 of an 8-bit recorded RGB image (the sRGB curve, or as it is)."""
    e = recorded.astype(np.float32) / 255
    if encoding == "linear":
        return e
    return np.where(e <= 0.04045, e / 12.92, ((e + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _to_8bit(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint16:
        return np.round(image / 257).astype(np.uint8)
    return image


def _read_rgb(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SystemExit(f"cannot read {path}")
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, -1)
    return _to_8bit(image[..., 2::-1] if image.shape[-1] >= 3 else image)


def _mask_file(folder: Path) -> Path | None:
    for name in ("undistorted_mask.bmp", "mask.png", "mask.bmp"):
        if (folder / name).is_file():
            return folder / name
    return None


def sequences(args) -> list[tuple[str, list[np.ndarray], np.ndarray | None, str]]:
    """(name, recorded 8-bit frames, field-of-view mask or None, encoding) per sequence."""
    out = []
    folders = []
    if not args.captures:
        if not SHARED.is_dir():
            print(f"skipped: {SHARED} not found (the shared real data)", file=sys.stderr)
        else:
            sinus = SHARED / "jhu-sinus-a"
            if (sinus / "images").is_dir():
                folders.append(sinus)
            else:
                print(f"skipped: {sinus}/images not found", file=sys.stderr)
            video = SHARED / "lap-video" / "cholecystectomy.mp4"
            if video.is_file():
                out.append(("lap-video", _video_frames(video, args.video_frames), None, "srgb"))
            else:
                print(f"skipped: {video} not found", file=sys.stderr)
    folders += [Path(c) for c in args.captures]
    for folder in folders:
        files = sorted(
            p for p in (folder / "images").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
        )
        if not files:
            print(f"skipped: no images in {folder / 'images'}", file=sys.stderr)
            continue
        camera = folder / "camera.json"
        encoding = "srgb"
        if camera.is_file():
            encoding = json.loads(camera.read_text()).get("encoding", "srgb")
        frames = [_read_rgb(p) for p in files[:: args.every]]
        mask = _mask_file(folder)
        fov = None
        if mask is not None and args.fov == "file":
            fov = cv2.imread(str(mask), cv2.IMREAD_GRAYSCALE) > 127
        out.append((folder.name, frames, fov, encoding))
    return out


def _video_frames(path: Path, count: int) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(path))
    total = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    frames = []
    for index in np.linspace(0, total - 1, count).round().astype(int):
        capture.set(cv2.CAP_PROP_POS_FRAMES, int(index))
        ok, frame = capture.read()
        if ok:
            frames.append(frame[..., ::-1])
    capture.release()
    return frames


def _shrink(image: np.ndarray, scale: int) -> np.ndarray:
    if scale == 1:
        return image
    height, width = image.shape[:2]
    size = (round(width / scale), round(height / scale))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def _fields_of_view(frames, fov, scale) -> list[np.ndarray]:
    if fov is None:
        return visible_masks([frame.astype(np.float32) / 255 for frame in frames])
    small = _shrink(fov.astype(np.float32), scale) >= 0.5
    return [small] * len(frames)


def figures(recorded: np.ndarray, visible: np.ndarray, specular: np.ndarray, scale: int):
    """(cores, cores in S, S, dilated cores, field of view) pixel counts of one frame."""
    radius = max(1, round(RIM_PX / scale))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    inner = cv2.erode(visible.astype(np.uint8), disk).astype(bool)
    cores = np.all(recorded >= CORE_LEVEL, axis=-1) & inner
    dilated = cv2.dilate(cores.astype(np.uint8), DILATION).astype(bool)
    return np.array(
        [cores.sum(), (cores & specular).sum(), specular.sum(), dilated.sum(), visible.sum()]
    )


def measure(name, frames, fov, encoding, scale, rules, per_frame):
    recorded = [_shrink(frame, scale) for frame in frames]
    visible = _fields_of_view(recorded, fov, scale)
    height, width = recorded[0].shape[:2]
    rows = {}
    for label, rule in rules.items():
        total, seconds, misses = np.zeros(5), 0.0, []
        for index, (frame, inside) in enumerate(zip(recorded, visible, strict=True)):
            image = decode(frame, encoding)
            started = time.perf_counter()
            specular = specular_mask(image, rule, visible=inside)
            seconds += time.perf_counter() - started
            counts = figures(frame, inside, specular, scale)
            total += counts
            recall = counts[1] / counts[0] if counts[0] else float("nan")
            ratio = counts[2] / counts[3] if counts[3] else float("inf") if counts[2] else 0.0
            if per_frame:
                print(
                    f"    {label:8s} 1/{scale} frame {index:3d}: cores {counts[0]:7.0f}  "
                    f"S {counts[2]:7.0f}  recall {recall:6.3f}  ratio {ratio:7.2f}"
                )
            if (counts[0] and recall < 0.95) or ratio > 3:
                misses.append(index)
        rows[label] = {
            "sequence": name,
            "rule": label,
            "scale": f"1/{scale}",
            "size": f"{width}x{height}",
            "frames": len(recorded),
            "cores_px": int(total[0]),
            "S_px": int(total[2]),
            "recall": float(total[1] / total[0]) if total[0] else None,
            "S_over_dilated_cores": float(total[2] / total[3]) if total[3] else None,
            "S_share_of_fov": float(total[2] / total[4]) if total[4] else None,
            "frames_missing_the_goal": misses,
            "seconds_per_frame": seconds / len(recorded),
        }
    return rows


def _fmt(value, spec):
    return "-" if value is None else format(value, spec)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("captures", nargs="*", help="capture folders (images/, camera.json)")
    parser.add_argument("--scales", type=int, nargs="+", default=[1, 3])
    parser.add_argument("--every", type=int, default=1, help="every n-th frame of a folder")
    parser.add_argument("--video-frames", type=int, default=12)
    parser.add_argument("--rule", choices=("both", *RULES), default="both")
    parser.add_argument("--fov", choices=("file", "computed"), default="file")
    parser.add_argument("--per-frame", action="store_true", help="one line per frame too")
    args = parser.parse_args()
    rules = RULES if args.rule == "both" else {args.rule: RULES[args.rule]}
    results = []
    for name, frames, fov, encoding in sequences(args):
        height, width = frames[0].shape[:2]
        source = "mask file" if fov is not None else "visible_masks"
        print(f"\n{name}: {len(frames)} frames {width}x{height}, field of view from {source}")
        print(
            f"  {'rule':8s} {'scale':5s} {'size':>9s} {'cores px':>9s} {'S px':>9s} "
            f"{'recall':>7s} {'S/dil':>6s} {'S/fov':>7s} {'s/frame':>7s}  frames off goal"
        )
        for scale in args.scales:
            rows = measure(name, frames, fov, encoding, scale, rules, args.per_frame)
            for row in rows.values():
                print(
                    f"  {row['rule']:8s} {row['scale']:5s} {row['size']:>9s} "
                    f"{row['cores_px']:9d} {row['S_px']:9d} {_fmt(row['recall'], '7.3f')} "
                    f"{_fmt(row['S_over_dilated_cores'], '6.2f')} "
                    f"{_fmt(row['S_share_of_fov'], '7.4f')} {row['seconds_per_frame']:7.2f}  "
                    f"{len(row['frames_missing_the_goal'])}/{row['frames']}"
                )
                results.append(row)
        sys.stdout.flush()
    print()
    for row in results:
        emit(row)


if __name__ == "__main__":
    main()
