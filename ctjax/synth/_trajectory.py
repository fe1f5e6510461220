"""A rigid exploration trajectory of the laparoscope over the organ."""

import numpy as np


def look_at(centre: np.ndarray, target: np.ndarray, down: np.ndarray) -> np.ndarray:
    """Camera-to-world 4x4 of a camera at `centre` looking at `target`, image y along `down`."""
    forward = target - centre
    forward = forward / np.linalg.norm(forward)
    right = np.cross(down, forward)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, forward, centre
    return pose


def exploration(frames: int, rng: np.random.Generator, base_mm: float) -> list[np.ndarray]:
    """`frames` poses sweeping an arc of about 20 mm, each looking at a point of the organ.

    The first pose is close to the world frame; the others translate by up to ~12 mm and
    rotate by up to ~12 degrees, as a surgeon's exploratory motion does.
    """
    phase = rng.uniform(0, 2 * np.pi)
    poses = []
    for k in range(frames):
        s = k / max(frames - 1, 1)
        angle = phase + 1.4 * s
        centre = np.array([10 * s * np.cos(angle), 8 * s * np.sin(angle), -4 * s])
        centre += rng.normal(0, 0.6, 3) * (k > 0)
        target = np.array([3 * s * np.cos(angle + 1), 3 * s * np.sin(angle + 1), base_mm])
        target += rng.normal(0, 1.0, 3) * (k > 0)
        down = np.array([np.sin(0.15 * s), np.cos(0.15 * s), 0.0])
        poses.append(look_at(centre, target, down))
    return poses
