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


def local_tissue(image: np.ndarray, tissue: np.ndarray, window: float) -> np.ndarray:
    """(H, W, 3) float32: the median colour around each pixel over a window of `window`
    times the image's width; pixels outside `tissue` count as the median colour of those in
    it (the black border does not darken the tissue beside it, nor a highlight whiten it)."""
    height, width = tissue.shape
    pixels = image[tissue] if tissue.any() else image.reshape(-1, 3)
    fill = np.median(pixels[::SUBSAMPLE], axis=0).astype(np.float32)
    scale = min(1.0, _WORKING_WIDTH / width)
    small_size = (max(1, round(width * scale)), max(1, round(height * scale)))
    # Downscale first: the mean of the tissue pixels in each cell, the fill where a cell
    # is mostly not tissue.
    weight = tissue.astype(np.float32)
    small = cv2.resize(image * weight[..., None], small_size, interpolation=cv2.INTER_AREA)
    share = cv2.resize(weight, small_size, interpolation=cv2.INTER_AREA)[..., None]
    small = np.where(share >= 0.5, small / np.maximum(share, 1e-6), fill)
    small = np.clip(np.round(small * 255), 0, 255).astype(np.uint8)
    kernel = max(3, round(window * small_size[0]) | 1)
    kernel = min(kernel, 2 * (min(small_size) // 2) - 1) if min(small_size) >= 3 else 1
    if kernel >= 3:
        small = cv2.medianBlur(small, kernel)
    out = cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR)
    return out.astype(np.float32) / 255
