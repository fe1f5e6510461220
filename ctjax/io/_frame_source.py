"""Where `ctjax import` reads frames from: a video file (any format OpenCV decodes) or a
folder of images, which stands for a video whose frames are its files in name order. Each
error names the file: a video OpenCV cannot open (with the decoder's own complaint), a folder
without images, an image it cannot read or of another size than the folder's first."""

import contextlib
import os
import re
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from .._errors import CaptureError
from ._images import IMAGE_SUFFIXES

# A folder of images stands for a video whose frames are its files in name order, one per
# "second": --start and --end count files.
FOLDER_FPS = 1.0


def image_files(path: Path) -> list[Path] | None:
    """A folder's images in name order (its frames), or None where `path` is not a folder."""
    if not path.is_dir():
        return None
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise CaptureError(
            f"{path}: a folder without images ({', '.join(IMAGE_SUFFIXES)}): nothing to import"
        )
    return files


def read_frame(path: Path) -> np.ndarray:
    """One image of a folder as a video frame (BGR, 8 bits a channel)."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise CaptureError(f"{path}: cannot read the image")
    return image


def open_video(path: Path) -> cv2.VideoCapture:
    if not path.is_file():
        raise CaptureError(f"{path}: video file (or folder of images) not found")
    # The decoders write their complaints (FFmpeg's "moov atom not found") to the process's
    # stderr, before ctjax's one line: caught here, and named in it.
    with _stderr_caught() as said:
        video = cv2.VideoCapture(str(path))
        opened = video.isOpened()
    if not opened:
        why = re.sub(r"[^\x20-\x7e]", "?", " ".join(said())).strip()
        raise CaptureError(
            f"{path}: cannot open the video (not a video OpenCV can decode"
            + (f": {why[:200]}" if why else "")
            + ")"
        )
    return video


@contextlib.contextmanager
def _stderr_caught():
    """File descriptor 2 into a temporary file while in the block; yields a function giving
    its lines, without the decoders' "[mov,mp4 @ 0x...]" prefixes."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        text: list[str] = []
        try:
            yield lambda: text
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            caught.seek(0)
            lines = caught.read().decode("utf-8", "replace").splitlines()
            text.extend(re.sub(r"^\[[^\]]*\] ", "", line) for line in lines if line.strip())


def frame_size(path: Path) -> tuple[int, int]:
    """The frames' size, (width, height): the first image's for a folder."""
    files = image_files(path)
    if files is not None:
        height, width = read_frame(files[0]).shape[:2]
        return width, height
    video = open_video(path)
    width = int(video.get(cv2.CAP_PROP_FRAME_WIDTH))
    height = int(video.get(cv2.CAP_PROP_FRAME_HEIGHT))
    video.release()
    if width <= 0 or height <= 0:
        raise CaptureError(f"{path}: the video does not say its frame size")
    return width, height


def rate_and_count(path: Path) -> tuple[float, int]:
    """Frames per second (`FOLDER_FPS` for a folder; 25 where a video does not say) and the
    number of frames (0 where a video does not say)."""
    files = image_files(path)
    if files is not None:
        return FOLDER_FPS, len(files)
    video = open_video(path)
    fps = video.get(cv2.CAP_PROP_FPS) or 25.0
    total = int(video.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    video.release()
    return fps, total


def frames(path: Path, first: int, last: int | None, every: int):
    """(frame number, BGR uint8 image) of frames `first`, `first + every`, ... up to `last`
    (None: the end), decoding only those."""
    files = image_files(path)
    if files is not None:
        size = None
        for index, file in enumerate(files[: None if last is None else last + 1]):
            if index >= first and (index - first) % every == 0:
                image = read_frame(file)
                if size is not None and image.shape != size:
                    raise CaptureError(
                        f"{file}: {image.shape[1]}x{image.shape[0]} px where the folder's "
                        f"first frame is {size[1]}x{size[0]}"
                    )
                size = image.shape
                yield index, image
        return
    video = open_video(path)
    index = 0
    try:
        while last is None or index <= last:
            if index < first or (index - first) % every:
                if not video.grab():
                    return
            else:
                ok, image = video.read()
                if not ok:
                    return
                yield index, image
            index += 1
    finally:
        video.release()
