"""A procedural tissue albedo texture: mottling at several scales and a vessel network.

Fine enough for SIFT at laparoscope distances (features of 0.5-3 mm), defined in world
coordinates so that every view sees the same tissue. The map multiplies the diffuse weight
per channel and has mean 1 over the organ, so `rho_tilde` stays the average albedo.

A camera's pixel integrates the light over its footprint on the tissue: a texture sampled
at pixel centres alone aliases wherever a pixel covers several texels (0.49 mm, 4.5 texels,
at 160x128 and 70 mm), and an albedo then changes from view to view with how the pixel
grid falls. `seeded_texture` prefilters the texture for the capture's pixel footprint with
the pixel's own box (as a Gaussian of the same spread), the optics taken as sharp. Measured
on `ctjax diagnose` (160x128 x 6, seed 11, the albedo map): the noise floor, 1 level of
noise plus what the texture's interpolation across views leaves, 4.2 -> 2.9 levels, and a
hidden GGX lowers the held-out RMSE by 6.5% instead of 3.6%. A Gaussian of half a pixel
(the optics as blurred as the box) went further (floor 1.9 levels) but took the texture
detail that SfM's texture refinement of the normals uses: the demo's F_tilde -10% instead
of -1% (`benchmarks/sfm_bias.py`, seed 0).
"""

import functools

import cv2
import numpy as np

EXTENT_MM = 110.0  # the texture covers [-EXTENT_MM, EXTENT_MM]^2 of the world (x, y) plane
RESOLUTION = 2048
TEXEL_MM = 2 * EXTENT_MM / (RESOLUTION - 1)
# The prefilter: a Gaussian of this many pixel footprints (standard deviation), that of the
# pixel's box (1 / sqrt(12)).
PREFILTER_PIXELS = 0.29


def tissue_texture(rng: np.random.Generator) -> np.ndarray:
    """(RESOLUTION, RESOLUTION, 3) float32 multiplier of the diffuse albedo, mean 1."""
    size = RESOLUTION
    mottling = np.zeros((size, size), np.float32)
    for sigma_px, amplitude in ((40, 0.5), (12, 0.4), (4, 0.35), (1.5, 0.25)):
        noise = rng.standard_normal((size, size)).astype(np.float32)
        blurred = cv2.GaussianBlur(noise, (0, 0), sigma_px)
        mottling += amplitude * blurred / (blurred.std() + 1e-12)
    mottling /= mottling.std()
    vessels = np.zeros((size, size), np.float32)
    for _ in range(60):
        points = [rng.uniform(0, size, 2)]
        heading = rng.uniform(0, 2 * np.pi)
        for _ in range(int(rng.integers(8, 30))):
            heading += rng.normal(0, 0.35)
            points.append(
                points[-1] + rng.uniform(10, 30) * np.array([np.cos(heading), np.sin(heading)])
            )
        polyline = np.round(np.array(points)).astype(np.int32)[:, None, :]
        cv2.polylines(
            vessels,
            [polyline],
            False,
            float(rng.uniform(0.5, 1.0)),
            thickness=int(rng.integers(2, 7)),
            lineType=cv2.LINE_AA,
        )
    vessels = cv2.GaussianBlur(vessels, (0, 0), 1.2)
    # Glands and pits: small dark and light spots, the blob-like features SIFT locks onto.
    spots = np.zeros((size, size), np.float32)
    for _ in range(9000):
        centre = tuple(int(c) for c in rng.integers(0, size, 2))
        radius = int(rng.integers(3, 13))
        cv2.circle(spots, centre, radius, float(rng.choice([-1.0, 0.6])), -1, cv2.LINE_AA)
    spots = cv2.GaussianBlur(spots, (0, 0), 1.5)
    # Reddish tissue: mottling and spots modulate all channels, vessels darken green and
    # blue most.
    channel_mottling = np.array([0.14, 0.22, 0.22], np.float32)
    channel_vessels = np.array([0.3, 0.5, 0.45], np.float32)
    channel_spots = np.array([0.18, 0.3, 0.3], np.float32)
    texture = (
        1
        + mottling[..., None] * channel_mottling
        - vessels[..., None] * channel_vessels
        + spots[..., None] * channel_spots
    )
    texture = np.clip(texture, 0.3, 1.7)
    return (texture / texture.mean(axis=(0, 1))).astype(np.float32)


def seeded_texture(seed: np.random.SeedSequence, pixel_mm: float = 0.0) -> np.ndarray:
    """`tissue_texture` of a generator seeded by `seed`, read-only, as a camera whose pixels
    cover `pixel_mm` of tissue sees it (prefiltered; 0: as made); the last few are kept
    (1.4 s each to make: a process synthesising several captures of one seed, e.g. a test
    session, makes it once)."""
    sigma_texels = round(PREFILTER_PIXELS * pixel_mm / TEXEL_MM, 2)
    return _prefiltered(seed.entropy, tuple(seed.spawn_key), seed.pool_size, sigma_texels)


@functools.lru_cache(maxsize=3)
def _prefiltered(entropy, spawn_key, pool_size, sigma_texels: float) -> np.ndarray:
    texture = _texture_of(entropy, spawn_key, pool_size)
    if sigma_texels < 0.3:  # pixels finer than the texels: nothing to integrate
        return texture
    blurred = cv2.GaussianBlur(texture, (0, 0), sigma_texels, borderType=cv2.BORDER_REFLECT)
    blurred.setflags(write=False)
    return blurred


@functools.lru_cache(maxsize=3)
def _texture_of(entropy, spawn_key, pool_size) -> np.ndarray:
    seed = np.random.SeedSequence(entropy, spawn_key=spawn_key, pool_size=pool_size)
    texture = tissue_texture(np.random.default_rng(seed))
    texture.setflags(write=False)
    return texture


def sample_texture(texture: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """Bilinear lookup of the texture at world (x, y) points (H, W, 3); 1 where NaN."""
    sampled = _remapped(texture, points_world)
    return np.where(np.isfinite(points_world[..., :1]), sampled, 1.0).astype(np.float32)


def sample_field(field: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a one-channel field over the texture's square (RESOLUTION^2) at
    world (x, y) points (H, W); 0 where NaN."""
    sampled = _remapped(field, points_world)
    return np.where(np.isfinite(points_world[..., 0]), sampled, 0.0).astype(np.float32)


def _remapped(image: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    scale = (RESOLUTION - 1) / (2 * EXTENT_MM)
    map_x = ((points_world[..., 0] + EXTENT_MM) * scale).astype(np.float32)
    map_y = ((points_world[..., 1] + EXTENT_MM) * scale).astype(np.float32)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
