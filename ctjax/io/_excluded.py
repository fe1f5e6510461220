"""Pixels that are not tissue, given per frame: surgical instruments, gauze, smoke.

    CAPTURE/excluded/NAME.png         optional: frame NAME's pixels that are not tissue
                                      (non-zero), on the recorded image's grid
    CAPTURE/excluded/right/NAME.png   optional: the same for its right image (stereo)
    CAPTURE/excluded.png              optional: pixels excluded in every frame (an overlay
                                      the loader does not find itself: text that changes)

An instrument moves with the surgeon, not with the tissue, and a metal one shines: its
pixels are neither the rigid scene that structure-from-motion reconstructs nor the tissue
whose reflectance ctjax measures, and its highlights would be taken for the tissue's (a
white object is whiter than the tissue around it: `ctjax.specular.WhiterThanTissue`).
Most surgical datasets that show instruments ship their masks (EndoNeRF, StereoMIS, the
EndoVis instrument segmentation challenges); ctjax does not find instruments itself. The
loader takes the excluded pixels out of each frame's field of view, so that no command
uses them: SfM finds no features there, no highlight, ring pixel, track or held-out value
lies there. Any single-channel or colour image of the frame's size: a pixel is excluded
where any of its channels is non-zero.
"""

from pathlib import Path

import cv2
import numpy as np

from .._errors import CaptureError
from ._images import IMAGE_SUFFIXES

EXCLUDED = "excluded"


def excluded_path(root: Path, name: str, *, right: bool = False) -> Path | None:
    """Frame `name`'s excluded pixels (`excluded/NAME.*`, `excluded/right/NAME.*` for its
    right image), None where the capture gives none."""
    folder = root / EXCLUDED / ("right" if right else "")
    for suffix in IMAGE_SUFFIXES:
        path = folder / f"{name}{suffix}"
        if path.is_file():
            return path
    return None


def read_excluded(path: Path, size: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the non-zero pixels of the mask at `path`, whose size must be `size`
    (height, width)."""
    mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if mask is None or mask.size == 0:
        raise CaptureError(f"{path}: cannot read the excluded pixels' mask (not an image file)")
    if mask.shape[:2] != tuple(size):
        raise CaptureError(
            f"{path}: mask is {mask.shape[1]}x{mask.shape[0]}, its frame {size[1]}x{size[0]}"
        )
    return np.any(mask.reshape(*size, -1) != 0, axis=-1)


def check_excluded_names(root: Path, names: set[str]) -> None:
    """One `CaptureError` naming a mask in `excluded/` (or `excluded/right/`) that belongs
    to no frame: a misnamed mask would otherwise leave its frame's instrument in."""
    for folder in (root / EXCLUDED, root / EXCLUDED / "right"):
        if not folder.is_dir():
            continue
        stray = sorted(
            p.name
            for p in folder.iterdir()
            if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES and p.stem not in names
        )
        if stray:
            raise CaptureError(
                f"{folder}: {', '.join(stray[:3])}{' ...' if len(stray) > 3 else ''} "
                "names no frame of the capture (a mask is named as its frame's image)"
            )


def always_excluded(root: Path, size: tuple[int, int]) -> np.ndarray | None:
    """The pixels `excluded.png` excludes in every frame (H, W), None without the file."""
    for suffix in IMAGE_SUFFIXES:
        path = root / f"{EXCLUDED}{suffix}"
        if path.is_file():
            return read_excluded(path, size)
    return None


def excluded_pixels(
    root: Path, name: str, size: tuple[int, int], *, right: bool = False
) -> np.ndarray | None:
    """Frame `name`'s excluded pixels (H, W) on its recorded grid (of its right image with
    `right`), None where the capture gives none."""
    path = excluded_path(root, name, right=right)
    return None if path is None else read_excluded(path, size)
