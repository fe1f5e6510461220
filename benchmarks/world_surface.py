"""Prototype, not in the library: one smooth world surface fitted jointly with the BRDF.

    python benchmarks/world_surface.py [--size 640x512] [--seed 1] [--knot-mm 2]
        [--smoothing 1] [--iterations 10] [--max-points 8000]

Why (README, "Shape from images"): from images alone the BRDF's error is the normals' error
around the highlights (1-5 degrees after SfM and the texture refinement; the specular
changes 16-29% per degree there). Neither the texture nor normals fitted per point to the
shading fix it (per point, a tilted normal explains a dimmer lobe's tail). A highlight
sweeps over the surface as the camera moves, so ONE surface shared by every frame must
explain every frame's rim at once.

What: a capture from `tests/independent.py` (a renderer that shares no code with ctjax) is
reconstructed from its images (`ctjax.sfm.reconstruct`, texture refinement included); its
surface points are tracked across frames (`Observations.tracks`); a correction of the world
height field z = h(x, y) (world = the reference camera's frame), a cubic B-spline with knots
every `--knot-mm`, changes every tracked point's normal (its position is kept), and is fitted
jointly with sigma by Levenberg-Marquardt (Jacobian by `jax.linearize` in chunks of
parameters), each point's albedo and F_tilde eliminated in closed form
(`projected_residuals`), with a second-difference penalty (`--smoothing`, in 8-bit levels
per mm^-1 of curvature). One sample per observation (corner-weighted point and normal), not
the fit's four bilinear corners. Prints per iteration: F_tilde's and sigma's errors, the
cost and the normals' median / 90th percentile error (degrees) at the tracked points.
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from independent import Scene, _reconstructed, render_capture  # noqa: E402

from ctjax._vector import Vec3  # noqa: E402
from ctjax.estimation._albedo_map import fit_brdf_map, projected_residuals, track_shading  # noqa: E402
from ctjax.estimation._brdf import PAPER, design_columns  # noqa: E402
from ctjax.io import load_capture  # noqa: E402
from ctjax.observations import Observations, ShadingSamples  # noqa: E402


def _bspline(t):
    """Cubic B-spline weights of the 4 knots around fractional positions t, and their slopes."""
    b = np.stack([(1 - t) ** 3, 3 * t**3 - 6 * t**2 + 4, -3 * t**3 + 3 * t**2 + 3 * t + 1, t**3])
    db = np.stack([-3 * (1 - t) ** 2, 9 * t**2 - 12 * t, -9 * t**2 + 6 * t + 3, 3 * t**2])
    return b.T / 6, db.T / 6


class Problem:
    """The tracked points of a capture with their world positions, SfM normals, the true
    normals (for the figures) and the spline's slope weights."""

    def __init__(self, capture, truth, knot_mm, max_points):
        tracks = Observations.of(capture).tracks(max_points=max_points)
        rotations = np.stack([f.pose[:3, :3] for f in capture.frames])
        shifts = np.stack([f.pose[:3, 3] for f in capture.frames])
        count = len(tracks)
        point = np.sum(tracks.corner_point * tracks.corner_weight[..., None], axis=2)
        normal = np.sum(tracks.corner_normal * tracks.corner_weight[..., None], axis=2)
        rotation = rotations[np.where(tracks.observed, tracks.frame, 0)]
        world_normal = np.einsum("pmij,pmj->pmi", rotation, normal) * tracks.observed[..., None]
        start = np.nan_to_num(world_normal).sum(1)
        own = np.argmax((tracks.frame == tracks.anchor_frame[:, None]) & tracks.observed, axis=1)
        anchor = rotations[tracks.anchor_frame]
        world = np.einsum("pij,pj->pi", anchor, point[np.arange(count), own])
        world += shifts[tracks.anchor_frame]
        keep = np.linalg.norm(start, axis=-1) > 0
        keep &= tracks.observed[np.arange(count), own] & np.all(np.isfinite(world), -1)
        self.kept = int(keep.sum())
        self.shading = track_shading(tracks)
        start = start[keep] / np.linalg.norm(start[keep], axis=-1, keepdims=True)
        world, self.anchor = world[keep], anchor[keep]
        self.rotation = jnp.asarray(rotation[keep])
        view = -point[keep] / np.maximum(np.linalg.norm(point[keep], axis=-1, keepdims=True), 1e-9)
        self.view = jnp.asarray(view)
        values = np.nan_to_num(tracks.values[keep])
        self.values = jnp.asarray(np.transpose(values, (2, 1, 0)))  # (C, M, P)
        self.weight = jnp.asarray(tracks.weight[keep].T)  # (M, P)
        self.start_slope = jnp.asarray(-start[:, :2] / start[:, 2:])  # h_x, h_y of SfM
        anchors = (tracks.anchor_frame[keep], tracks.anchor_row[keep], tracks.anchor_col[keep])
        rows = zip(*anchors, strict=True)
        self.true_normal = np.stack([truth.frames[f].normals[r, c] for f, r, c in rows])
        self.start = start
        lo = world[:, :2].min(0) - 1e-6
        self.knots = (np.ceil((world[:, :2].max(0) - lo) / knot_mm).astype(int) + 3)[::-1]
        gx, gy = ((world[:, :2] - lo) / knot_mm).T
        ix, iy = np.floor(gx).astype(int), np.floor(gy).astype(int)
        bx, dbx = _bspline(gx - ix)
        by, dby = _bspline(gy - iy)
        rows, cols = iy[:, None, None] + np.arange(4)[:, None], ix[:, None, None] + np.arange(4)
        self.index = jnp.asarray((rows * self.knots[1] + cols).reshape(-1, 16))
        self.slope_x = jnp.asarray((by[:, :, None] * dbx[:, None, :]).reshape(-1, 16) / knot_mm)
        self.slope_y = jnp.asarray((dby[:, :, None] * bx[:, None, :]).reshape(-1, 16) / knot_mm)

    @property
    def coefficients(self) -> int:
        return int(np.prod(self.knots))

    def normals(self, c):
        """World normals (P, 3) of the corrected surface: n ~ (h_x, h_y, -1)."""
        hx = self.start_slope[:, 0] + jnp.sum(c[self.index] * self.slope_x, -1)
        hy = self.start_slope[:, 1] + jnp.sum(c[self.index] * self.slope_y, -1)
        n = jnp.stack([hx, hy, -jnp.ones_like(hx)], -1)
        return n / jnp.linalg.norm(n, axis=-1, keepdims=True)

    def angle_error(self, world_normal) -> tuple[float, float]:
        camera = np.einsum("pji,pj->pi", self.anchor, np.asarray(world_normal))
        cosine = np.clip(np.sum(camera * self.true_normal, -1), -1, 1)
        error = np.degrees(np.arccos(cosine))
        return float(np.nanmedian(error)), float(np.nanpercentile(error, 90))

    def residuals(self, theta, smoothing, normals=None):
        """Weighted residuals (albedo and F_tilde eliminated) and the penalty, and F_tilde."""
        c, sigma = theta[:-1], theta[-1]
        n = self.normals(c) if normals is None else normals
        camera = jnp.einsum("pmji,pj->pmi", self.rotation, n)
        flat = lambda a, k: a[..., k].T.ravel()  # noqa: E731  (M, P) order, flattened
        normal = Vec3(flat(camera, 0), flat(camera, 1), flat(camera, 2))
        m = camera.shape[1]
        view = Vec3(*(flat(self.view, k) for k in range(3)))
        size = normal.x.shape[0]
        samples = ShadingSamples(normal, view, view, jnp.ones(size), jnp.zeros((size, 3)))
        columns = design_columns(PAPER, sigma[None], samples)
        columns = tuple(col.reshape(m, -1) for col in columns)
        _, weights, residual = projected_residuals(columns, self.values, self.weight, 0)
        grid = c.reshape(self.knots)
        penalty = jnp.concatenate(
            [
                (grid[2:] - 2 * grid[1:-1] + grid[:-2]).ravel(),
                (grid[:, 2:] - 2 * grid[:, 1:-1] + grid[:, :-2]).ravel(),
                np.sqrt(2)
                * (grid[1:, 1:] - grid[1:, :-1] - grid[:-1, 1:] + grid[:-1, :-1]).ravel(),
            ]
        )
        return jnp.concatenate([residual.ravel(), smoothing / 255 * penalty]), weights[1]


def _normal_equations(problem, theta, smoothing, chunk=16):
    def residual(t):
        return problem.residuals(t, smoothing)[0]

    @jax.jit
    def columns(t, basis):
        return jax.vmap(jax.linearize(residual, t)[1], in_axes=1, out_axes=1)(basis)

    n = theta.shape[0]
    eye = np.eye(n)
    blocks = []
    for start in range(0, n, chunk):
        basis = np.pad(eye[:, start : start + chunk], ((0, 0), (0, max(0, start + chunk - n))))
        blocks.append(np.asarray(columns(theta, jnp.asarray(basis)), np.float32))
    jacobian = np.concatenate(blocks, 1)[:, :n].astype(np.float64)
    r = np.asarray(jax.jit(residual)(theta))
    return jacobian.T @ jacobian, jacobian.T @ r, float(r @ r)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="640x512")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--knot-mm", type=float, default=2.0)
    parser.add_argument("--smoothing", type=float, default=1.0)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--max-points", type=int, default=8000)
    args = parser.parse_args()
    width, height = map(int, args.size.split("x"))
    scene = Scene()
    folder = Path(tempfile.mkdtemp(prefix="ctjax-world-surface-"))
    render_capture(folder, width, height, 8, args.seed, scene)
    images_only = _reconstructed(folder, photometric=True)
    problem = Problem(
        load_capture(images_only), load_capture(folder), args.knot_mm, args.max_points
    )
    first = fit_brdf_map(problem.shading, PAPER)
    sigma = float(first.params[0])
    print(
        f"{problem.kept} points, {problem.coefficients} coefficients; BnB on SfM's normals: "
        f"sigma {100 * (sigma / scene.sigma - 1):+.1f}%, "
        f"normals {np.round(problem.angle_error(problem.start), 2).tolist()}"
    )
    truth = jnp.asarray(np.einsum("pij,pj->pi", problem.anchor, problem.true_normal))
    zero = jnp.concatenate([jnp.zeros(problem.coefficients), jnp.asarray([scene.sigma])])
    r, f_tilde = problem.residuals(zero, 0.0, truth)
    print(
        f"true normals and sigma: cost {float(r @ r):.4g}, F_tilde "
        f"{np.round(100 * (np.asarray(f_tilde) / scene.F - 1), 1).tolist()}% "
        "(one sample per observation)"
    )
    theta, damping = zero.at[-1].set(sigma), 1e-3
    residual = jax.jit(lambda t: problem.residuals(t, args.smoothing))
    for iteration in range(args.iterations):
        started = time.perf_counter()
        a, g, cost = _normal_equations(problem, theta, args.smoothing)
        while damping < 1e8:
            step = -np.linalg.solve(a + damping * np.diag(np.diag(a) + 1e-9), g)
            trial = theta + jnp.asarray(step)
            if float(trial[-1]) > 0.01 and float(jnp.sum(residual(trial)[0] ** 2)) < cost:
                theta, damping = trial, damping * 0.3
                break
            damping *= 10
        f_tilde = np.asarray(residual(theta)[1])
        print(
            f"iteration {iteration}: sigma {100 * (float(theta[-1]) / scene.sigma - 1):+.1f}%, "
            f"F_tilde {np.round(100 * (f_tilde / scene.F - 1), 1).tolist()}%, cost {cost:.4g}, "
            f"normals {np.round(problem.angle_error(problem.normals(theta[:-1])), 2).tolist()} "
            f"({time.perf_counter() - started:.0f} s)",
            flush=True,
        )
        if damping >= 1e8:
            break


if __name__ == "__main__":
    main()
