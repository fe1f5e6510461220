"""The world surface of the shading refinement (`_shading.py`): a height field z = h(x, y)
over the reference camera's plane as a cubic B-spline, its slopes and normals, and its fit
to every frame's depth."""

import dataclasses

import jax.numpy as jnp
import numpy as np
from scipy import sparse


def _bspline(t):
    """Cubic B-spline weights (N, 4) of the 4 knots around fractional positions t, and their
    derivatives."""
    b = np.stack([(1 - t) ** 3, 3 * t**3 - 6 * t**2 + 4, -3 * t**3 + 3 * t**2 + 3 * t + 1, t**3])
    db = np.stack([-3 * (1 - t) ** 2, 9 * t**2 - 12 * t, -9 * t**2 + 6 * t + 3, 3 * t**2])
    return b.T / 6, db.T / 6


@dataclasses.dataclass(frozen=True)
class HeightSpline:
    """A cubic B-spline dh(x, y) over the world plane: knots every `spacing` from `origin`,
    coefficients (rows = y, cols = x)."""

    origin: np.ndarray
    spacing: float
    shape: tuple[int, int]

    @classmethod
    def covering(cls, xy: np.ndarray, spacing: float) -> "HeightSpline":
        origin = xy.min(0) - 1e-9
        count = np.ceil((xy.max(0) - origin) / spacing).astype(int) + 3
        return cls(origin, spacing, (int(count[1]), int(count[0])))

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    def basis(self, xy: np.ndarray):
        """For points (N, 2): coefficient indices (N, 16), weights of the value, of d/dx
        and of d/dy (N, 16 each), and whether the point lies inside the knots' span."""
        g = (xy - self.origin) / self.spacing
        cell = np.floor(g).astype(int)
        inside = np.all((cell >= 0) & (cell <= np.array(self.shape[::-1]) - 4), axis=-1)
        cell = np.clip(cell, 0, np.array(self.shape[::-1]) - 4)
        bx, dbx = _bspline(g[:, 0] - cell[:, 0])
        by, dby = _bspline(g[:, 1] - cell[:, 1])
        rows = cell[:, 1, None, None] + np.arange(4)[:, None]
        cols = cell[:, 0, None, None] + np.arange(4)
        index = (rows * self.shape[1] + cols).reshape(-1, 16)
        value = (by[:, :, None] * bx[:, None, :]).reshape(-1, 16)
        d_x = (by[:, :, None] * dbx[:, None, :]).reshape(-1, 16) / self.spacing
        d_y = (dby[:, :, None] * bx[:, None, :]).reshape(-1, 16) / self.spacing
        return index, value, d_x, d_y, inside

    def penalty(self, c):
        """The coefficients' second differences along y, along x and across."""
        return second_differences(self.shape, c)

    def penalty_matrix(self) -> sparse.csr_matrix:
        """`penalty` as a sparse matrix (it is linear in the coefficients)."""
        rows, cols = self.shape
        second = lambda k: sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], (k - 2, k))  # noqa: E731
        first = lambda k: sparse.diags([-1.0, 1.0], [0, 1], (k - 1, k))  # noqa: E731
        return sparse.vstack(
            [
                sparse.kron(second(rows), sparse.eye(cols)),
                sparse.kron(sparse.eye(rows), second(cols)),
                np.sqrt(2) * sparse.kron(first(rows), first(cols)),
            ]
        ).tocsr()


def second_differences(shape: tuple[int, int], c):
    grid = c.reshape(shape)
    return jnp.concatenate(
        [
            (grid[2:] - 2 * grid[1:-1] + grid[:-2]).ravel(),
            (grid[:, 2:] - 2 * grid[:, 1:-1] + grid[:, :-2]).ravel(),
            np.sqrt(2) * (grid[1:, 1:] - grid[1:, :-1] - grid[:-1, 1:] + grid[:-1, :-1]).ravel(),
        ]
    )


def _slopes(world_normal):
    """Height-field slopes (h_x, h_y) of world normals facing the reference camera (-z)."""
    return -world_normal[..., :2] / world_normal[..., 2:]


def normals_from_slopes(hx, hy, xp=np):
    n = xp.stack([hx, hy, -xp.ones_like(hx)], -1)
    return n / xp.linalg.norm(n, axis=-1, keepdims=True)


def world_pixels(frame, camera, every: int = 1):
    """(rows, cols) of a frame's pixels with depth and normals, their rays (z = 1), depth
    and world positions."""
    valid = np.isfinite(frame.depth) & np.all(np.isfinite(frame.normals), -1)
    rows, cols = np.nonzero(valid)
    rows, cols = rows[::every], cols[::every]
    z = frame.depth[rows, cols].astype(np.float64)
    ray = np.stack(
        [
            (cols - float(camera.cx)) / float(camera.fx),
            (rows - float(camera.cy)) / float(camera.fy),
            np.ones_like(z),
        ],
        -1,
    )
    world = (ray * z[:, None]) @ frame.pose[:3, :3].T + frame.pose[:3, 3]
    return rows, cols, ray, z, world


def base_surface(capture, spline: "HeightSpline", samples: int = 200_000) -> np.ndarray:
    """Coefficients of one world height field fitted (least squares, a light second-difference
    penalty) to every frame's depth: the frames' surfaces fused into one."""
    worlds = [world_pixels(f, capture.camera)[4] for f in capture.frames]
    world = np.concatenate(worlds)
    world = world[:: max(1, len(world) // samples)]
    index, value, _, _, inside = spline.basis(world[:, :2])
    index, value, z = index[inside], value[inside], world[inside, 2]
    rows = np.repeat(np.arange(len(z)), 16)
    design = sparse.csr_matrix((value.ravel(), (rows, index.ravel())), (len(z), spline.size))
    normal = (design.T @ design).toarray()
    rhs = design.T @ z
    penalty = spline.penalty_matrix()
    penalty = (penalty.T @ penalty).toarray()
    scale = np.trace(normal) / np.trace(penalty)
    return np.linalg.solve(
        normal + 1e-3 * scale * penalty + 1e-9 * scale * np.eye(spline.size), rhs
    )
