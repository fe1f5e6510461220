"""Real-like endoscopic frames (2D, no geometry) for the highlight and field-of-view
detectors' tests and benchmarks: nothing is downloaded.

Three kinds after the frames ctjax is meant for:
- "liver": in-vivo, bright, red-brown textured tissue with vessels and pale fat, clipped
  highlights with a tinted halo, a black circular border;
- "dim": the same scene at a third of the exposure: no highlight reaches the top;
- "colon": a colonoscope's frame: the red channel clips over much of the tissue, a black
  octagonal border, a white UI icon on the tissue and white text on the border.
Each frame comes with its truth: the field of view, the icon, and the highlight's share of
every pixel (`specular`, the added white light, before clipping).
"""

import dataclasses

import cv2
import numpy as np

from .._errors import ParameterError


@dataclasses.dataclass
class RealLikeFrame:
    image: np.ndarray  # (H, W, 3) float32 in [0, 1], 8-bit levels
    inside: np.ndarray  # (H, W) bool: the endoscope's field of view
    icon: np.ndarray  # (H, W) bool: the UI icon (none: all False)
    specular: np.ndarray  # (H, W) float: the highlight added to every channel

    @property
    def near_white(self) -> np.ndarray:
        """The highlight pixels a user sees: in the field of view, off the icon, where the
        highlight is at least twice the tissue's brightest channel (near white)."""
        tissue = np.max(self.image, -1) - self.specular
        return (self.specular >= 2 * np.maximum(tissue, 0.02)) & self.inside & ~self.icon


def _smooth_noise(rng, shape, scale_px, octaves=3):
    height, width = shape
    out = np.zeros(shape, np.float32)
    for k in range(octaves):
        size = max(2, round(max(height, width) / (scale_px / 2**k)))
        small = rng.normal(size=(size, size)).astype(np.float32)
        out += cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC) / 2**k
    return out / np.std(out)


KINDS = ("liver", "dim", "colon")


def real_like_frame(
    kind: str = "liver", width: int = 480, height: int = 270, seed: int = 0
) -> RealLikeFrame:
    """One frame of `kind` ("liver", "dim" or "colon", see the module doc)."""
    if kind not in KINDS:
        raise ParameterError(f"kind must be one of {KINDS}, got {kind!r}")
    rng = np.random.default_rng(seed)
    scale = width / 1920
    v, u = np.mgrid[0:height, 0:width].astype(np.float32)
    # Albedo: reddish tissue, a per-channel texture, dark vessels, pale fat.
    base = {"colon": (0.95, 0.52, 0.45)}.get(kind, (0.62, 0.28, 0.2))
    texture = _smooth_noise(rng, (height, width), 300 * scale)
    albedo = np.stack([c * (1 + 0.12 * texture * (1 + 0.5 * k)) for k, c in enumerate(base)], -1)
    vessels = np.abs(_smooth_noise(rng, (height, width), 600 * scale)) < 0.06
    albedo[vessels] *= (0.6, 0.35, 0.4)
    fat = _smooth_noise(rng, (height, width), 900 * scale) > 1.3
    albedo[fat] = (0.8, 0.68, 0.45)
    # Shading: the near light's falloff from the centre, folds.
    r2 = ((u - width / 2) ** 2 + (v - height / 2) ** 2) / (0.6 * width) ** 2
    shading = (0.55 + 0.6 * np.exp(-2 * r2)) * (
        1 + 0.15 * _smooth_noise(rng, r2.shape, 500 * scale)
    )
    exposure = {"dim": 0.3, "colon": 1.25}.get(kind, 1.0)
    image = albedo * shading[..., None] * exposure
    # Highlights: elongated Gaussian lobes, a few large and many small, slightly tinted.
    specular = np.zeros((height, width), np.float32)
    for _ in range(int(rng.integers(14, 22))):
        cu, cv_ = rng.uniform(0.15, 0.85) * width, rng.uniform(0.15, 0.85) * height
        size = rng.choice([3.0, 6.0, 12.0, 25.0], p=[0.4, 0.3, 0.2, 0.1]) * scale * 2
        angle = rng.uniform(0, np.pi)
        du, dv = u - cu, v - cv_
        a = (du * np.cos(angle) + dv * np.sin(angle)) / (size * rng.uniform(1.0, 2.5))
        b = (-du * np.sin(angle) + dv * np.cos(angle)) / size
        specular += rng.uniform(0.8, 2.5) * np.exp(-0.5 * (a * a + b * b))
    specular *= exposure
    icon = np.zeros((height, width), np.uint8)
    if kind == "colon":  # a UI icon on the tissue, off the highlights
        side = max(14, int(40 * scale))
        top, left = height // 4, width // 2 - height // 4
        cv2.rectangle(icon, (left, top), (left + side, top + side // 2), 1, -1)
        cv2.circle(icon, (left + side // 2, top + side + 2), side // 3, 1, -1)
        specular *= cv2.distanceTransform(1 - icon, cv2.DIST_L2, 5) > 4 * side
    image = image + specular[..., None] * np.array([1.0, 0.97, 0.93], np.float32)
    image = image + rng.normal(0, 1.5 / 255, image.shape)
    # The border and the overlays.
    inside = np.zeros((height, width), np.uint8)
    radius = int(0.48 * height) if kind != "colon" else int(0.52 * height)
    centre = (width // 2, height // 2)
    if kind == "colon":
        angles = np.radians(22.5 + 45 * np.arange(8))
        points = np.stack(
            [centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)], -1
        )
        cv2.fillPoly(inside, [np.round(points).astype(np.int32)], 1)
    else:
        cv2.circle(inside, centre, radius, 1, -1)
    inside = inside.astype(bool)
    image[~inside] = rng.uniform(0, 3 / 255, ((~inside).sum(), 1))
    if kind == "colon":
        text = np.zeros((height, width), np.uint8)  # a timestamp, white on the border
        cv2.putText(
            text,
            "12:04:31",
            (4, height - 8),
            cv2.FONT_HERSHEY_SIMPLEX,
            2.4 * scale,
            255,
            max(1, int(2 * scale)),
        )
        image[icon.astype(bool)] = 1.0
        image[text > 0] = (text[text > 0] / 255.0)[:, None]
    image = np.clip(np.round(np.clip(image, 0, 1) * 255) / 255, 0, 1).astype(np.float32)
    return RealLikeFrame(image, inside, icon.astype(bool), specular)
