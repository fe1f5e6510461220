"""The endoscope's field of view on real-like frames: a black circular (or octagonal)
border and a white overlay icon constant over the video; nothing outside the scene may
reach S, the ring or the fits."""

import cv2
import numpy as np
import pytest

from ctjax import Camera
from ctjax.cli import main
from ctjax.io import Frame, field_of_view, load_capture, overlay_mask, write_capture

WIDTH, HEIGHT = 160, 120


def read_mask(path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127


ICON = (slice(6, 16), slice(140, 152))  # a white UI icon in the top-right corner


def _tissue(shift: float, seed: int) -> np.ndarray:
    """A textured reddish tissue image with one clipped highlight, moving with
    `shift` (px) as a camera would move over it."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(float)
    u = u + shift
    texture = 0.8 + 0.1 * np.sin((u + 0.7 * v) / 5.0) + 0.1 * np.sin((u - 0.4 * v) / 3.0)
    image = np.stack([0.62 * texture, 0.30 * texture, 0.22 * texture], -1)
    bump = np.exp(-((u - 80 - shift) ** 2 + (v - 60) ** 2) / (2 * 5.0**2))  # the highlight
    image = image + 1.2 * bump[..., None]
    image = image + rng.normal(0, 1 / 255, image.shape)
    return np.clip(image, 0, 1).astype(np.float32)


def _border(shape: str) -> np.ndarray:
    """True inside the endoscope's image: a circle, or an octagon."""
    mask = np.zeros((HEIGHT, WIDTH), np.uint8)
    if shape == "circle":
        cv2.circle(mask, (WIDTH // 2, HEIGHT // 2), 56, 1, -1)
    else:
        r, c = 56, (WIDTH // 2, HEIGHT // 2)
        angles = np.radians(22.5 + 45 * np.arange(8))
        points = np.stack([c[0] + r * np.cos(angles), c[1] + r * np.sin(angles)], -1)
        cv2.fillPoly(mask, [np.round(points).astype(np.int32)], 1)
    return mask.astype(bool)


def _frames(shape: str, count: int = 8) -> tuple[list[np.ndarray], np.ndarray]:
    inside = _border(shape)
    images = []
    for k in range(count):
        image = _tissue(shift=2.0 * k, seed=k)
        image[~inside] = np.random.default_rng(10 + k).uniform(0, 4 / 255, (~inside).sum())[:, None]
        image[ICON] = 1.0  # the overlay: white, constant
        images.append(image)
    return images, inside


@pytest.mark.parametrize("shape", ["circle", "octagon"])
def test_field_of_view_is_the_image_circle_less_its_rim(shape):
    images, inside = _frames(shape)
    fov = field_of_view(images[0])
    assert not np.any(fov & ~inside)  # nothing of the border
    # All of the image but a rim of a few pixels (the margin and the polygon's rounding).
    assert fov.sum() >= 0.9 * inside.sum()


def test_the_lens_edge_is_not_in_view():
    """A sinus scope's image circle ends in a dim halo just above the border's level, a
    black line and a white ring (the lens's edge): none of it is the scene; a highlight
    on the tissue beside the ring, and the tissue itself, are."""
    images, inside = _frames("circle", count=1)
    image = images[0]
    distance = cv2.distanceTransform(inside.astype(np.uint8), cv2.DIST_L2, 3)
    edge = {
        "halo": (distance > 0) & (distance <= 2),
        "line": (distance > 2) & (distance <= 3),
        "ring": (distance > 3) & (distance <= 5),
    }
    image[edge["halo"]] = [0.07, 0.06, 0.05]  # above the border's 0.06, yet not tissue
    image[edge["line"]] = 0.01
    image[edge["ring"]] = 0.93
    image[58:62, 33:37] = 1.0  # a clipped highlight on the tissue 3 px inside the ring
    fov = field_of_view(image)
    for name, pixels in edge.items():
        assert not (fov & pixels).any(), name
    assert fov[58:62, 33:37].all()
    assert fov.sum() >= 0.9 * (distance > 5).sum()  # the tissue inside the ring
    # Without a ring (a laparoscope's image circle), dark tissue by the border is tissue.
    image = _frames("circle", count=1)[0][0]
    shadow = (distance > 0) & (distance <= 4) & (np.arange(WIDTH) < 60)[None, :]
    image[shadow] = [0.08, 0.03, 0.02]
    fov = field_of_view(image)
    assert fov[shadow & (distance > 2)].all()  # all but the 1-px margin


def test_a_capture_without_border_is_all_in_view():
    image = _tissue(0.0, 0)
    assert field_of_view(image).all()
    image[40:42, :70] = 0.01  # a thin dark vessel reaching the edge is tissue, not border
    assert field_of_view(image).all()


def test_overlay_is_what_stays_constant_while_the_scene_moves():
    images, _ = _frames("circle")
    overlay = overlay_mask(images)
    assert overlay[ICON].all()
    assert overlay.sum() <= 2 * overlay[ICON].size + 100  # the icon and its dilated edge
    # The highlight's clipped core stays put in the image while the tissue moves: not an
    # overlay (its surroundings stay white).
    assert not overlay[50:71, 70:91].any()
    # A still camera shows nothing to tell an overlay from the scene; nor do a few frames.
    assert not overlay_mask([images[0]] * 8).any()
    assert not overlay_mask(images[:7]).any()


def test_masks_never_reach_outside_the_field_of_view(tmp_path):
    images, inside = _frames("octagon")
    camera = Camera(WIDTH, HEIGHT, 150.0, 150.0, WIDTH / 2 - 0.5, HEIGHT / 2 - 0.5)
    depth = np.full((HEIGHT, WIDTH), 60.0, np.float32)  # a plane facing the camera
    frames = [Frame(f"frame_{k:03d}", image, depth) for k, image in enumerate(images)]
    root = write_capture(tmp_path / "capture", camera, frames)
    capture = load_capture(root)
    for frame in capture.frames:
        assert frame.field_of_view is not None
        assert not frame.visible[ICON].any() and not np.any(frame.visible & ~inside)
        assert not np.any(frame.geometry_mask & ~frame.visible)
    out = tmp_path / "masks"
    assert main(["masks", str(root), "--out", str(out), "--ring-px", "10"]) == 0
    for frame in capture.frames:
        fov = read_mask(out / "fov" / f"{frame.name}.png")
        np.testing.assert_array_equal(fov, frame.visible)
        for kind in ("specular", "ring", "saturated"):
            mask = read_mask(out / kind / f"{frame.name}.png")
            assert not np.any(mask & ~fov), kind  # the white icon is not a highlight
        assert read_mask(out / "specular" / f"{frame.name}.png").any()  # the real highlight
        assert read_mask(out / "ring" / f"{frame.name}.png").any()
