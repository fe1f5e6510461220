"""Image pyramids for shape from shading: block-averaged images, their cameras, and log
depth carried from a coarse level to the next finer one."""

import cv2
import numpy as np

from .._camera import Camera


def reduced(camera: Camera, factor: int) -> Camera:
    """The camera of an image reduced by an integer `factor` (block averages)."""
    if factor == 1:
        return camera
    return Camera(
        camera.width // factor,
        camera.height // factor,
        camera.fx / factor,
        camera.fy / factor,
        (camera.cx + 0.5) / factor - 0.5,
        (camera.cy + 0.5) / factor - 0.5,
    )


def block_reduce(array: np.ndarray, factor: int, reduce=np.mean) -> np.ndarray:
    """(H, W, ...) -> (H // factor, W // factor, ...): `reduce` over factor x factor blocks
    (the mean for images, `np.all` for masks)."""
    if factor == 1:
        return array
    height, width = array.shape[0] // factor, array.shape[1] // factor
    cropped = array[: height * factor, : width * factor]
    blocks = cropped.reshape(height, factor, width, factor, *array.shape[2:])
    return reduce(blocks, axis=(1, 3))


def fill_outside(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """`values` (H, W) with every pixel outside `mask` set to its nearest pixel's inside."""
    _, label = cv2.distanceTransformWithLabels(
        (~mask).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    lookup = np.zeros(label.max() + 1)
    rows, cols = np.nonzero(mask)
    lookup[label[rows, cols]] = values[rows, cols]
    return lookup[label]


def resample(values: np.ndarray, mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A map known on `mask` (e.g. log depth) bilinearly resampled to `shape` (H, W), pixel
    centres aligned (edges extended from the nearest known pixel)."""
    height, width = shape
    return cv2.resize(fill_outside(values, mask), (width, height), interpolation=cv2.INTER_LINEAR)
