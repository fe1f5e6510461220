"""Per-pixel colour helpers shared by the field of view and the highlight rules: channel
extremes, luminance, and the local tissue colour (a median filter at a reduced size)."""

import cv2
import numpy as np

# The local tissue is estimated on a copy at most this wide (px): the median is a smooth
# field, and the filter's cost grows with the window's area.
_WORKING_WIDTH = 256
# Medians of a frame's pixels are taken on every this many-th (a 1080p frame: 300k).
SUBSAMPLE = 7


def channel_max(image: np.ndarray) -> np.ndarray:
    """(H, W): the brightest channel (NumPy's reduction over a last axis of 3 is ~10x
    slower than two elementwise maxima)."""
    return np.maximum(np.maximum(image[..., 0], image[..., 1]), image[..., 2])


def channel_min(image: np.ndarray) -> np.ndarray:
    """(H, W): the least channel."""
    return np.minimum(np.minimum(image[..., 0], image[..., 1]), image[..., 2])


def luminance(image: np.ndarray) -> np.ndarray:
    """(H, W): Rec. 709 luminance of linear RGB."""
    return 0.2126 * image[..., 0] + 0.7152 * image[..., 1] + 0.0722 * image[..., 2]


FILLS = ("median", "nearest")


def local_tissue(
    image: np.ndarray, tissue: np.ndarray, window: float, *, fill: str = "median"
) -> np.ndarray:
    """(H, W, 3) float32: the median colour around each pixel over a window of `window`
    times the image's width. Pixels outside `tissue` count (`fill`) as the median colour of
    those in it ("median": the black border does not darken the tissue beside it, nor a
    highlight whiten it) or as the nearest tissue ("nearest", at the working size): beside
    the border, or beside a large hole in `tissue`, the median is then that of the tissue
    there, not a mix with the frame's median (which is redder than a pale wall)."""
    return local_tissues(image, tissue, (window,), fill=fill)[0]


def local_tissues(
    image: np.ndarray, tissue: np.ndarray, windows, *, fill: str = "median"
) -> list[np.ndarray]:
    """`local_tissue` for each of `windows`, from one reduced copy."""
    if fill not in FILLS:
        raise ValueError(f"fill must be one of {FILLS}, got {fill!r}")
    height, width = tissue.shape
    scale = min(1.0, _WORKING_WIDTH / width)
    small_size = (max(1, round(width * scale)), max(1, round(height * scale)))
    # Downscale first: the mean of the tissue pixels in each cell; where a cell is mostly
    # not tissue, the fill.
    weight = tissue.astype(np.float32)
    small = cv2.resize(image * weight[..., None], small_size, interpolation=cv2.INTER_AREA)
    share = cv2.resize(weight, small_size, interpolation=cv2.INTER_AREA)
    inside = share >= 0.5
    small = small / np.maximum(share, 1e-6)[..., None]
    if fill == "nearest" and inside.any():
        if not inside.all():
            small = _nearest_filled(small, inside)
    else:
        pixels = image[tissue] if tissue.any() else image.reshape(-1, 3)
        median = np.median(pixels[::SUBSAMPLE], axis=0).astype(np.float32)
        small = np.where(inside[..., None], small, median)
    small = np.clip(np.round(small * 255), 0, 255).astype(np.uint8)
    out = []
    for window in windows:
        kernel = max(3, round(window * small_size[0]) | 1)
        kernel = min(kernel, 2 * (min(small_size) // 2) - 1) if min(small_size) >= 3 else 1
        filtered = cv2.medianBlur(small, kernel) if kernel >= 3 else small
        filtered = cv2.resize(filtered, (width, height), interpolation=cv2.INTER_LINEAR)
        out.append(filtered.astype(np.float32) / 255)
    return out


def _nearest_filled(small: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """`small` with each cell outside `inside` replaced by its nearest inside cell."""
    # The labels number the zero pixels of the input (the inside cells).
    _, labels = cv2.distanceTransformWithLabels(
        (~inside).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    colours = np.zeros((labels.max() + 1, 3), np.float32)
    colours[labels[inside]] = small[inside]
    return colours[labels]
