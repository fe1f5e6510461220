"""A procedural tissue albedo texture: mottling at several scales and a vessel network.

Fine enough for SIFT at laparoscope distances (features of 0.5-3 mm), defined in world
coordinates so that every view sees the same tissue. The map multiplies the diffuse weight
per channel and has mean 1 over the organ, so `rho_tilde` stays the average albedo.
"""

import functools

import cv2
import numpy as np

EXTENT_MM = 110.0  # the texture covers [-EXTENT_MM, EXTENT_MM]^2 of the world (x, y) plane
RESOLUTION = 2048


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


def seeded_texture(seed: np.random.SeedSequence) -> np.ndarray:
    """`tissue_texture` of a generator seeded by `seed`, read-only; the last few are kept
    (1.4 s each to make: a process synthesising several captures of one seed, e.g. a test
    session, makes it once)."""
    return _texture_of(seed.entropy, tuple(seed.spawn_key), seed.pool_size)


@functools.lru_cache(maxsize=3)
def _texture_of(entropy, spawn_key, pool_size) -> np.ndarray:
    seed = np.random.SeedSequence(entropy, spawn_key=spawn_key, pool_size=pool_size)
    texture = tissue_texture(np.random.default_rng(seed))
    texture.setflags(write=False)
    return texture


def sample_texture(texture: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """Bilinear lookup of the texture at world (x, y) points (H, W, 3); 1 where NaN."""
    scale = (RESOLUTION - 1) / (2 * EXTENT_MM)
    map_x = ((points_world[..., 0] + EXTENT_MM) * scale).astype(np.float32)
    map_y = ((points_world[..., 1] + EXTENT_MM) * scale).astype(np.float32)
    sampled = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return np.where(np.isfinite(points_world[..., :1]), sampled, 1.0).astype(np.float32)
