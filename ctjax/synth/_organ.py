"""An organ-like smooth surface (a dome with lobes and folds) and ray casting onto it.

World frame: the first laparoscope pose looks along +z at the organ, x right, y down, mm.
The surface is a height field `z = organ_depth(x, y)` (depth grows away from the camera),
smooth and with slopes well below the camera's ray slopes, so every ray meets it once.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


class OrganSurface(eqx.Module):
    """`z = base_mm + (x^2 + y^2) / (2 radius_mm) - sum_i A_i exp(-|p - c_i|^2 / (2 s_i^2))`.

    A pytree that `cast_rays` traces: one compilation per image size serves every organ.
    """

    base_mm: float
    radius_mm: float
    centres_mm: np.ndarray  # (B, 2) c_i
    heights_mm: np.ndarray  # (B,) A_i
    # (B,) 2 s_i^2, in NumPy float64 whatever JAX's precision (float32 captures keep their bits).
    spreads_mm2: np.ndarray

    @classmethod
    def random(cls, rng: np.random.Generator, base_mm: float = 70.0) -> "OrganSurface":
        count = 9
        angles = rng.uniform(0, 2 * np.pi, count)
        radii = rng.uniform(0, 35, count)
        centres = np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=-1)
        radius = float(rng.uniform(110, 150))
        heights = rng.uniform(3.0, 8.0, count) * rng.choice([-1.0, 1.0], count, p=[0.3, 0.7])
        widths = rng.uniform(7, 15, count)
        return cls(base_mm, radius, centres, heights, 2 * widths**2)

    def depth(self, x, y):
        """Height field z(x, y) in mm (JAX, differentiable)."""
        dome = (x * x + y * y) / (2 * self.radius_mm)
        dx = x - self.centres_mm[:, 0]
        dy = y - self.centres_mm[:, 1]
        bumps = self.heights_mm * jnp.exp(-(dx * dx + dy * dy) / self.spreads_mm2)
        return self.base_mm + dome - jnp.sum(bumps)

    def intersect(self, origin, direction, iterations: int = 40):
        """First hit of the ray `origin + t direction` (world, mm); NaN where Newton fails.

        Newton's steps until they are a few ulps of t (6-8 here: it converges
        quadratically from the dome's base plane), at most `iterations`. Returns the world
        point and the unit world normal facing the ray's origin.
        """
        gradient = jax.grad(self.depth, argnums=(0, 1))

        def residual(t):
            p = origin + t * direction
            return p[2] - self.depth(p[0], p[1])

        def unconverged(state):
            t, step, count = state
            return (jnp.abs(step) > 4 * jnp.finfo(t.dtype).eps * jnp.abs(t)) & (count < iterations)

        def newton(state):
            t, _, count = state
            r, slope = jax.value_and_grad(residual)(t)
            return t - r / slope, r / slope, count + 1

        t0 = (self.base_mm - origin[2]) / direction[2]
        # Under `vmap` every ray steps until the slowest has converged: a fixed count
        # (40 before) cost 4x the time for the same depths to 1e-12 mm.
        t, _, _ = jax.lax.while_loop(unconverged, newton, (t0, jnp.full_like(t0, jnp.inf), 0))
        point = origin + t * direction
        ok = (jnp.abs(residual(t)) < 1e-4) & (t > 0)
        zx, zy = gradient(point[0], point[1])
        normal = jnp.stack([zx, zy, -jnp.ones_like(zx)])
        normal = normal / jnp.linalg.norm(normal)
        return jnp.where(ok, point, jnp.nan), jnp.where(ok, normal, jnp.nan)


@jax.jit
def _cast(surface: OrganSurface, rotation, centre, rays):
    """Camera-frame points and normals, and world points, where the camera-frame `rays`
    (N, 3) of a camera at `centre` with camera-to-world `rotation` meet the surface.
    Surface and pose are arguments, not constants: one compilation per image size."""
    directions = rays @ rotation.T
    points, normals = jax.vmap(surface.intersect, in_axes=(None, 0))(centre, directions)
    return (points - centre) @ rotation, normals @ rotation, points


def cast_rays(surface: OrganSurface, camera, pose: np.ndarray):
    """Depth (H, W) and camera-frame unit normals (H, W, 3) of the organ seen from `pose`,
    plus world points (H, W, 3); NaN where no hit. Default JAX precision (float32 unless
    x64 is on): far below a pixel at laparoscope distances."""
    u, v = np.meshgrid(
        np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64)
    )
    rays_camera = np.stack(
        [
            (u - float(camera.cx)) / float(camera.fx),
            (v - float(camera.cy)) / float(camera.fy),
            np.ones_like(u),
        ],
        axis=-1,
    ).reshape(-1, 3)
    points_camera, normals_camera, points_world = _cast(
        surface, jnp.asarray(pose[:3, :3]), jnp.asarray(pose[:3, 3]), jnp.asarray(rays_camera)
    )
    shape = (camera.height, camera.width)
    depth = np.asarray(points_camera[:, 2]).reshape(shape)
    normals = np.asarray(normals_camera).reshape(*shape, 3)
    return depth, normals, np.asarray(points_world).reshape(*shape, 3)
