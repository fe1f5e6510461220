"""Textured laparoscope captures from a renderer that shares no code with ctjax.

The surface, the texture, the camera path, the ray casting and the shading are written here
in plain NumPy, from the paper's eq. (1)-(2) (light at the camera centre), so that a test on
these captures checks ctjax against the physics and not against itself: a world height field
(a dome with bumps), a per-channel albedo texture defined analytically on the world plane
(sinusoids and spots, 1-20 mm), a camera sweeping over it, 1 level of Gaussian noise, 8 bits,
clipped highlights. The capture is written in the documented format (camera.json, images/,
depth/, optional normals/, poses.json) with OpenCV and json only; the true albedo of every
pixel is returned, not written into the capture.

    python tests/independent.py [--size 320x256] [--frames 8] [--seeds 1 2] [--no-normals]

prints the albedo map's acceptance figures (#15) for each seed.
"""

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np


@dataclasses.dataclass(frozen=True)
class Scene:
    rho: tuple[float, float, float] = (1.9, 0.95, 0.7)
    F: tuple[float, float, float] = (0.35, 0.33, 0.3)
    sigma: float = 0.25
    distance_mm: float = 68.0
    noise_levels: float = 1.0
    texture_strength: float = 1.0
    # The light: at the camera centre (the paper's), or a point light at this offset (mm,
    # camera frame), with inverse-square falloff normalised at `inverse_square_mm` if given.
    light_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inverse_square_mm: float | None = None


def _surface(seed: int, distance: float):
    """h(x, y) (world z of the surface, mm) and its gradient: a dome facing the camera with
    a few bumps."""
    rng = np.random.default_rng(1000 + seed)
    bumps = [
        (rng.uniform(-18, 18), rng.uniform(-14, 14), rng.uniform(-3, 3), rng.uniform(4, 9))
        for _ in range(5)
    ]

    def height(x, y):
        r2 = x * x + y * y
        h = distance - 10.0 * np.exp(-r2 / (2 * 32.0**2))
        hx = 10.0 * x / 32.0**2 * np.exp(-r2 / (2 * 32.0**2))
        hy = 10.0 * y / 32.0**2 * np.exp(-r2 / (2 * 32.0**2))
        for bx, by, amp, width in bumps:
            g = amp * np.exp(-((x - bx) ** 2 + (y - by) ** 2) / (2 * width**2))
            h = h - g
            hx = hx + g * (x - bx) / width**2
            hy = hy + g * (y - by) / width**2
        return h, hx, hy

    return height


def _texture(seed: int, strength: float):
    """Albedo multiplier per channel, an analytic function of world (x, y), mean about 1."""
    rng = np.random.default_rng(2000 + seed)
    waves = []
    for _ in range(14):
        wavelength = rng.uniform(1.5, 20.0)
        angle = rng.uniform(0, np.pi)
        k = 2 * np.pi / wavelength * np.array([np.cos(angle), np.sin(angle)])
        amplitude = rng.uniform(0.02, 0.07, 3) * rng.choice([-1, 1], 3)
        waves.append((k, amplitude, rng.uniform(0, 2 * np.pi, 3)))
    spots = [
        (
            *rng.uniform(-30, 30, 2),
            rng.uniform(0.6, 2.5),
            rng.uniform(-0.35, 0.25) * np.array([0.6, 1.0, 0.9]),
        )
        for _ in range(120)
    ]

    def texture(x, y):
        out = np.ones((*np.shape(x), 3))
        for k, amplitude, phase in waves:
            out += amplitude * np.sin((k[0] * x + k[1] * y)[..., None] + phase)
        for sx, sy, radius, colour in spots:
            out += colour * np.exp(-((x - sx) ** 2 + (y - sy) ** 2) / (2 * radius**2))[..., None]
        return np.clip(1 + strength * (out - 1), 0.3, 1.7)

    return texture


def _pose(centre, target, down):
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(down, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], axis=1)
    pose[:3, 3] = centre
    return pose


def _poses(frames: int, seed: int, distance: float):
    """A sweep of about 15 mm with the view turning towards the organ, as a surgeon's."""
    rng = np.random.default_rng(3000 + seed)
    poses = []
    for k in range(frames):
        s = k / max(frames - 1, 1)
        centre = np.array([-7 + 14 * s, 5 * np.sin(3 * s), -3 * s]) + rng.normal(0, 0.5, 3)
        target = np.array([2 * np.cos(2 * s), 2 * np.sin(2 * s), distance]) + rng.normal(0, 1, 3)
        down = np.array([np.sin(0.2 * s - 0.1), np.cos(0.2 * s - 0.1), 0.0])
        poses.append(_pose(centre, target, down))
    return poses


def _cast(height, pose, fx, fy, cx, cy, width, h_px, distance):
    """Camera-frame depth (H, W), world points (H, W, 3) and camera-frame normals."""
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(h_px, dtype=float))
    ray = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], -1)  # z = 1: t is depth
    rotation, centre = pose[:3, :3], pose[:3, 3]
    direction = ray @ rotation.T
    t = (distance - centre[2]) / direction[..., 2]
    for _ in range(40):  # Newton on c_z + t d_z - h(c_xy + t d_xy) = 0
        x = centre[0] + t * direction[..., 0]
        y = centre[1] + t * direction[..., 1]
        h, hx, hy = height(x, y)
        f = centre[2] + t * direction[..., 2] - h
        slope = direction[..., 2] - hx * direction[..., 0] - hy * direction[..., 1]
        t = t - f / slope
    x, y = centre[0] + t * direction[..., 0], centre[1] + t * direction[..., 1]
    h, hx, hy = height(x, y)
    assert np.max(np.abs(centre[2] + t * direction[..., 2] - h)) < 1e-9, "ray casting diverged"
    world = np.stack([x, y, h], -1)
    normal = np.stack([hx, hy, -np.ones_like(hx)], -1)  # faces the camera (world -z)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return t, world, normal @ rotation  # camera frame: R^T n


def _shade(scene: Scene, depth, normal, albedo, fx, fy, cx, cy):
    """The paper's eq. (1)-(2) with the light at `scene.light_offset_mm`:
    E (rho/pi N.L + F D(N.H) / (pi N.L N.V)), E the inverse-square factor (or 1)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    point = np.stack([(u - cx) / fx * depth, (v - cy) / fy * depth, depth], -1)
    unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)  # noqa: E731
    view = unit(-point)
    to_light = np.asarray(scene.light_offset_mm, float) - point
    light = unit(to_light)
    half = unit(light + view)
    n_l, n_v = np.sum(normal * light, -1), np.sum(normal * view, -1)
    lit = (n_l > 0) & (n_v > 0)
    cos = np.clip(np.sum(normal * half, -1), 1e-6, 1)
    tan2 = (1 - cos**2) / cos**2
    beckmann = np.exp(-tan2 / scene.sigma**2) / (scene.sigma**2 * cos**4)
    with np.errstate(divide="ignore", invalid="ignore"):
        specular = np.where(lit, beckmann / (np.pi * n_l * n_v), 0.0)
    diffuse = np.where(lit, n_l / np.pi, 0.0)
    irradiance = np.ones_like(depth)
    if scene.inverse_square_mm is not None:
        irradiance = scene.inverse_square_mm**2 / np.sum(to_light * to_light, -1)
    shading = albedo * diffuse[..., None] + np.asarray(scene.F) * specular[..., None]
    return irradiance[..., None] * shading


def render_capture(
    root,
    width: int = 320,
    height: int = 256,
    frames: int = 8,
    seed: int = 1,
    scene: Scene = Scene(),
    normals: bool = True,
    depth_noise_mm: float = 0.0,
):
    """Write a textured capture into `root`; returns the true albedo maps {NAME: (H, W, 3)}
    (rho_tilde per pixel, linear units). The image is rendered from the true geometry; the
    depth written has Gaussian noise of `depth_noise_mm` (a depth sensor's or SfM's)."""
    root = Path(root)
    for folder in ("images", "depth", "normals"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    fx = fy = 0.85 * width
    cx, cy = (width - 1) / 2, (height - 1) / 2
    (root / "camera.json").write_text(
        json.dumps(
            {"width": width, "height": height, "fx": fx, "fy": fy, "cx": cx, "cy": cy}
            | {"encoding": "linear"}
        )
    )
    surface, texture = _surface(seed, scene.distance_mm), _texture(seed, scene.texture_strength)
    rng = np.random.default_rng(4000 + seed)
    poses, albedos = {}, {}
    for index, pose in enumerate(_poses(frames, seed, scene.distance_mm)):
        name = f"img{index:02d}"
        depth, world, normal = _cast(
            surface, pose, fx, fy, cx, cy, width, height, scene.distance_mm
        )
        depth32, normal32 = depth.astype(np.float32), normal.astype(np.float32)
        albedo = np.asarray(scene.rho) * texture(world[..., 0], world[..., 1])
        linear = _shade(
            scene, depth32.astype(float), normal32.astype(float), albedo, fx, fy, cx, cy
        )
        noisy = linear + rng.normal(0, scene.noise_levels / 255, linear.shape)
        image = np.round(np.clip(noisy, 0, 1) * 255).astype(np.uint8)
        cv2.imwrite(str(root / "images" / f"{name}.png"), image[..., ::-1])
        noisy_depth = depth + rng.normal(0, depth_noise_mm, depth.shape) * (depth_noise_mm > 0)
        np.save(root / "depth" / f"{name}.npy", noisy_depth.astype(np.float32))
        if normals:
            np.save(root / "normals" / f"{name}.npy", normal32)
        poses[name] = pose.tolist()
        albedos[name] = albedo.astype(np.float32)
    if not normals:
        (root / "normals").rmdir()
    (root / "poses.json").write_text(json.dumps(poses))
    return albedos


def map_errors(albedos: dict, estimate):
    """Relative errors of the estimated maps over the pixels where both are finite, and the
    smallest per-frame coverage of the surface."""
    errors, coverage, channels = [], [], []
    for name, truth in albedos.items():
        estimated = estimate.arrays[f"albedo/{name}"]
        finite = np.isfinite(estimated)
        coverage.append(float(np.mean(np.all(finite, -1))))
        channels.append(float(np.mean(finite)))
        errors.append(np.abs(estimated[finite] / truth[finite] - 1))
    return np.concatenate(errors), min(coverage), min(channels)


def _reconstructed(folder: Path, photometric: bool, shading: bool = False) -> Path:
    """A copy of the capture's images and camera with the shape reconstructed from them."""
    import shutil

    from ctjax.sfm import reconstruct

    out = folder / "images-only"
    (out / "images").mkdir(parents=True)
    shutil.copy(folder / "camera.json", out / "camera.json")
    for image in sorted((folder / "images").iterdir()):
        shutil.copy(image, out / "images" / image.name)
    first = np.load(sorted((folder / "depth").iterdir())[0])
    reconstruct(out, scale_mm=float(np.nanmedian(first)), photometric=photometric, shading=shading)
    return out


def _main():
    import argparse
    import tempfile
    import time

    import jax

    jax.config.update("jax_enable_x64", True)
    from ctjax.estimation import fit_capture
    from ctjax.io import load_capture

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="320x256")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--strength", type=float, default=1.0)
    parser.add_argument("--no-normals", action="store_true")
    parser.add_argument("--depth-noise-mm", type=float, default=0.0)
    parser.add_argument(
        "--images-only",
        action="store_true",
        help="reconstruct the shape from the images (ctjax reconstruct, metric scale from the "
        "true median depth of the first frame) and fit on it",
    )
    parser.add_argument(
        "--no-photometric", action="store_true", help="with --images-only: SfM's points only"
    )
    parser.add_argument(
        "--shading",
        action="store_true",
        help="with --images-only: the shape refined by the shading (reconstruct --shading)",
    )
    args = parser.parse_args()
    width, height = map(int, args.size.split("x"))
    scene = Scene(texture_strength=args.strength)
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as folder:
            albedos = render_capture(
                folder,
                width,
                height,
                args.frames,
                seed,
                scene,
                normals=not args.no_normals,
                depth_noise_mm=args.depth_noise_mm,
            )
            started = time.perf_counter()
            if args.images_only:
                folder = _reconstructed(Path(folder), not args.no_photometric, args.shading)
            estimate = fit_capture(load_capture(folder))
            seconds = time.perf_counter() - started
        fit = estimate.to_json()
        errors, coverage, channels = map_errors(albedos, estimate)
        sigma_error = fit["sigma"] / scene.sigma - 1
        f_error = [f / t - 1 for f, t in zip(fit["F_tilde"], scene.F, strict=True)]
        print(
            f"seed {seed} {args.size} x{args.frames}: sigma {100 * sigma_error:+.2f}%, F_tilde "
            + " ".join(f"{100 * e:+.2f}%" for e in f_error)
            + f", map median {100 * np.median(errors):.2f}% p90 "
            f"{100 * np.percentile(errors, 90):.2f}%, coverage {100 * coverage:.1f}% of pixels "
            f"({100 * channels:.1f}% of channels; min over frames), {seconds:.1f} s"
        )
        for warning in estimate.warnings:
            print(f"  warning: {warning}")


if __name__ == "__main__":
    _main()
