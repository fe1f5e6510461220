"""Patch-averaged images: the paper's lobe as the average reflectance of many facets.

Wet tissue shows its specular lobe as sparkles: tiny facets, each lit only when its own
normal is along the half vector. The Beckmann lobe (paper eq. 2) describes what a patch of
many facets reflects on average; one pixel is one facet, lit by a sharp micro-lobe or not.
Averaging the linear intensity over k x k pixels (box, or a Gaussian of the same spread)
turns the sparkles back into that average. The smooth surface's normal at the patch centre
stays the pixel's normal; S and S~ are found on the original frames.

Clipped pixels lose energy (a sparkle at full scale holds more light than 1.0): `keep`
averages them at 1.0, `exclude` marks every patch holding one as clipped (1.0 in every
channel), which the fits drop as they drop clipped pixels.
"""

import dataclasses

import numpy as np

from .._errors import CtjaxError
from ..io import Capture

CLIPPED_CHOICES = ("exclude", "keep")
KERNELS = ("box", "gaussian")


def _average(values: np.ndarray, weight: np.ndarray, k: int, kernel: str) -> np.ndarray:
    """The weighted k x k average of `values` (H, W, C) with `weight` (H, W) in {0, 1}."""
    import cv2

    if kernel == "box":
        smooth = lambda a: cv2.blur(a, (k, k), borderType=cv2.BORDER_CONSTANT)  # noqa: E731
    else:
        # The box's standard deviation, k / sqrt(12), truncated at 3 of them.
        spread = k / np.sqrt(12.0)
        size = 2 * int(np.ceil(3 * spread)) + 1
        smooth = lambda a: cv2.GaussianBlur(  # noqa: E731
            a, (size, size), spread, borderType=cv2.BORDER_CONSTANT
        )
    w = weight.astype(np.float32)
    total = smooth(np.ascontiguousarray(values * w[..., None], np.float32))
    count = smooth(w)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = total / count[..., None]
    return np.where(count[..., None] > 1e-6, out, values).astype(np.float32)


def patch_averaged(
    capture: Capture, k: int, *, clipped: str = "keep", kernel: str = "box"
) -> Capture:
    """`capture` with every frame's (linear) image averaged over k x k patches of the pixels
    with geometry (or in view, without it); k = 1 returns `capture` itself."""
    if k < 1:
        raise CtjaxError(f"the patch size must be at least 1 pixel, got {k}")
    if clipped not in CLIPPED_CHOICES:
        raise CtjaxError(f"clipped must be one of {CLIPPED_CHOICES}, got {clipped!r}")
    if kernel not in KERNELS:
        raise CtjaxError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    if k == 1:
        return capture
    import cv2

    frames = []
    for frame in capture.frames:
        inside = frame.geometry_mask if frame.has_geometry else frame.visible
        image = _average(frame.image, inside, k, kernel)
        if clipped == "exclude":
            hit = np.any(frame.image >= 1.0, axis=-1) & inside
            near = cv2.blur(hit.astype(np.float32), (k, k), borderType=cv2.BORDER_CONSTANT)
            image[near > 0] = 1.0
        image = np.where(inside[..., None], np.minimum(image, 1.0), frame.image)
        frames.append(dataclasses.replace(frame, image=image.astype(np.float32)))
    return dataclasses.replace(capture, frames=tuple(frames))


def patch_observations(capture: Capture, masks, k: int, *, kernel: str = "box", clipped="keep"):
    """`Observations` whose images are `capture`'s averaged over k x k patches
    (`patch_averaged`) and whose sets S and S~ are found on the original frames (averaging
    spreads a sparkle into its neighbours, which would then read as tissue or as S)."""
    from ..observations import Observations

    original = Observations.of(capture, masks)
    if k == 1:
        return original
    averaged = Observations(
        patch_averaged(original.capture, k, clipped=clipped, kernel=kernel), masks
    )
    averaged.sets = original.sets  # fills the cached property: the original frames' sets
    return averaged


def clipped_share(capture: Capture, sets) -> float:
    """The share of S's pixels (over every frame) with a clipped channel: where a sparkle
    clips, its patch's average lacks the light above full scale."""
    specular = sum(int(s.specular.sum()) for s in sets)
    if specular == 0:
        return 0.0
    hit = sum(
        int((s.specular & np.any(f.image >= 1.0, axis=-1)).sum())
        for f, s in zip(capture.frames, sets, strict=True)
    )
    return hit / specular


def patch_summary(capture: Capture, sets, k: int, kernel: str) -> dict:
    """`ctjax fit --patch`'s `patch` block: the patch, the clipped share of S and, where
    sparkles clip, the warning that F_tilde is then a lower bound."""
    share = clipped_share(capture, sets)
    warnings = []
    if share > 0:
        warnings.append(
            f"--patch {k}: {100 * share:.0f}% of the specular pixels are clipped, and a "
            "clipped sparkle lacks the light above full scale in its patch's average: "
            "F_tilde is a lower bound (on synthetic sparkles it came 8-45x low and "
            "redder than the light; the fit guide, 'Patch-averaged images')"
        )
    return {
        "k": k,
        "kernel": kernel,
        "clipped": "kept at full scale",
        "clipped_specular_share": share,
        "note": "the linear images averaged over k x k pixels of the surface; S and S~ "
        "from the original frames (ctjax.estimation._patches)",
        "warnings": warnings,
    }
