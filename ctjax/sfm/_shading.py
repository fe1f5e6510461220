"""Shape refined by the shading: one smooth world surface, fitted with the BRDF to every frame.

Why. From images alone the BRDF's error is the normals' error around the highlights: after
SfM and the texture refinement (`_photometric.py`) they are 1-5 degrees off there, and where a
highlight's core is clipped the lobe is read on its tails, where the specular changes by
16-29% per degree (`ctjax.estimation._sensitivity`). The texture cannot fix them where it is
smooth at the pixel scale, and normals fitted per point to the shading do not either: per
point, a normal tilted towards the view explains a dimmer lobe's tail as well as the right
one explains the true lobe. But a highlight sweeps over the surface as the camera moves, so
ONE surface shared by every frame must explain every frame's rim at once.

What. The world (the reference camera's frame, as `reconstruct` writes it) is taken as a
height field z = h(x, y): a cubic B-spline over (x, y) with knots every `KNOT_FRACTION` of
the working distance, first fitted to every frame's depth (the frames' surfaces fused into
one, `base_surface`), then corrected, jointly with sigma, by Levenberg-Marquardt on the
tracked surface points' observations in every frame (`Observations.tracks`), each point's
albedo and F_tilde eliminated in closed form (`projected_residuals`; the paper's model, light
at the camera), with a second-difference penalty on the correction (`SMOOTHING`). The
correction changes each point's normal, n ~ (h_x, h_y, -1); the points stay where SfM put
them. Every frame's normals are then the world surface's, and its depth moves by the
correction along world z.

Measured with 3 mm knots (`benchmarks/world_surface.py`: tests/independent.py 640x512 x 8
reconstructed from its images, then `fit_capture` with the albedo map; 2 mm, now the
default: `KNOT_FRACTION`): seed 1 normals 3.65 -> 1.11 degrees
median, sigma +14.2% -> +2.1%, F_tilde -43..-52% -> +2.3..+2.7% (another run, SfM's result
varying: 3.72 -> 0.95 degrees, +13.0% -> +1.5%, -46..-54% -> -0.4..0.0%); seed 2 normals
1.61 -> 0.29, sigma +7.3% -> -0.1%, F_tilde -40..-42% -> -4.0%; 110-140 s.

It fits the paper's light (at the camera): on a capture whose light is elsewhere it would
bend the shape to fit the wrong light (and hide the offset from the near-light model), so
`ctjax reconstruct` does it only when asked (`--shading`); `ctjax fit` on a capture with
images only, which fits that same model, does it by default (`--no-shading`).
"""

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy import sparse

# Knot spacing over the median working distance: 2 mm at 68 mm. 3 mm knots left the rims'
# normals too smooth: on `ctjax synth` 640x512 x 8 (seed 1, images only) sigma -1.7% and
# F_tilde -6.6..-7.3%, with 2 mm -1.2% and -1.1..-1.6%; on tests/test_sfm.py's capture F_tilde
# -2.5..-2.2% against -0.2..+0.2%; tests/independent.py 640x512 seeds 1 and 2 the same within
# 0.3 points. (2 mm with a penalty of 1 instead of 10 overfit: the cost fell below the true
# normals'.)
KNOT_FRACTION = 0.03
# Second-difference penalty, in 8-bit levels per unit of coefficient second difference
# (1 with 2 mm knots overfit: the cost fell below the true normals').
SMOOTHING = 10.0
ITERATIONS = 10
# LM stops once an iteration lowers the cost by less than this fraction: on `ctjax synth`
# 640x512 x 8 (seed 1) the cost reached 0.6063 at the second iteration and the other eight
# lowered it in the fifth digit (sigma 0.1967 -> 0.1966), 20 s of Jacobian each.
RTOL = 1e-4
MAX_POINTS = 8000
# Jacobian columns computed at once (forward mode over the parameters).
_CHUNK = 16


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
        grid = c.reshape(self.shape)
        return jnp.concatenate(
            [
                (grid[2:] - 2 * grid[1:-1] + grid[:-2]).ravel(),
                (grid[:, 2:] - 2 * grid[:, 1:-1] + grid[:, :-2]).ravel(),
                np.sqrt(2)
                * (grid[1:, 1:] - grid[1:, :-1] - grid[:-1, 1:] + grid[:-1, :-1]).ravel(),
            ]
        )


def _slopes(world_normal):
    """Height-field slopes (h_x, h_y) of world normals facing the reference camera (-z)."""
    return -world_normal[..., :2] / world_normal[..., 2:]


def _normals_from_slopes(hx, hy, xp=np):
    n = xp.stack([hx, hy, -xp.ones_like(hx)], -1)
    return n / xp.linalg.norm(n, axis=-1, keepdims=True)


def _world_pixels(frame, camera, every: int = 1):
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
    worlds = [_world_pixels(f, capture.camera)[4] for f in capture.frames]
    world = np.concatenate(worlds)
    world = world[:: max(1, len(world) // samples)]
    index, value, _, _, inside = spline.basis(world[:, :2])
    index, value, z = index[inside], value[inside], world[inside, 2]
    rows = np.repeat(np.arange(len(z)), 16)
    design = sparse.csr_matrix((value.ravel(), (rows, index.ravel())), (len(z), spline.size))
    normal = (design.T @ design).toarray()
    rhs = design.T @ z
    penalty = jax.jacfwd(spline.penalty)(jnp.zeros(spline.size))
    penalty = np.asarray(penalty).T @ np.asarray(penalty)
    scale = np.trace(normal) / np.trace(penalty)
    return np.linalg.solve(
        normal + 1e-3 * scale * penalty + 1e-9 * scale * np.eye(spline.size), rhs
    )


class _Points:
    """Tracked surface points: each observation's rotation (camera to world) and view
    direction, the values and weights (views first), the SfM slopes at the points and the
    spline's basis there."""

    def __init__(self, capture, spline_spacing: float, max_points: int):
        from ..observations import Observations

        tracks = Observations.of(capture).tracks(max_points=max_points)
        rotations = np.stack([f.pose[:3, :3] for f in capture.frames])
        shifts = np.stack([f.pose[:3, 3] for f in capture.frames])
        count = len(tracks)
        point = np.sum(tracks.corner_point * tracks.corner_weight[..., None], axis=2)
        normal = np.sum(tracks.corner_normal * tracks.corner_weight[..., None], axis=2)
        rotation = rotations[np.where(tracks.observed, tracks.frame, 0)]
        world_normal = np.einsum("pmij,pmj->pmi", rotation, normal)
        start = np.sum(np.where(tracks.observed[..., None], np.nan_to_num(world_normal), 0), 1)
        # A point's world position from its own view, or its first view where its own
        # pixel is clipped (the highlights' cores: seen elsewhere, the most informative).
        own_slot = (tracks.frame == tracks.anchor_frame[:, None]) & tracks.observed
        slot = np.where(own_slot.any(1), np.argmax(own_slot, 1), np.argmax(tracks.observed, 1))
        frame = tracks.frame[np.arange(count), slot]
        world = np.einsum("pij,pj->pi", rotations[frame], point[np.arange(count), slot])
        world += shifts[frame]
        keep = (np.linalg.norm(start, axis=-1) > 0) & tracks.observed[np.arange(count), slot]
        keep &= np.all(np.isfinite(world), -1) & (start[:, 2] < 0)
        self.count = int(keep.sum())
        start = start[keep] / np.linalg.norm(start[keep], axis=-1, keepdims=True)
        self.spline = HeightSpline.covering(world[keep, :2], spline_spacing)
        self.index, _, self.d_x, self.d_y, _ = map(jnp.asarray, self.spline.basis(world[keep, :2]))
        self.base = base_surface(capture, self.spline)
        base = jnp.asarray(self.base)
        self.slopes = jnp.stack(
            [jnp.sum(base[self.index] * self.d_x, -1), jnp.sum(base[self.index] * self.d_y, -1)], -1
        )
        self.rotation = jnp.asarray(rotation[keep])
        view = -point[keep] / np.maximum(np.linalg.norm(point[keep], axis=-1, keepdims=True), 1e-9)
        self.view = jnp.asarray(np.where(tracks.observed[keep][..., None], view, [0, 0, 1.0]))
        self.values = jnp.asarray(np.transpose(np.nan_to_num(tracks.values[keep]), (2, 1, 0)))
        self.weight = jnp.asarray(np.where(tracks.observed[keep], tracks.weight[keep], 0).T)
        self.shading = tracks.select(np.nonzero(keep)[0])

    def normals(self, c):
        hx = self.slopes[:, 0] + jnp.sum(c[self.index] * self.d_x, -1)
        hy = self.slopes[:, 1] + jnp.sum(c[self.index] * self.d_y, -1)
        return _normals_from_slopes(hx, hy, jnp)

    def residuals(self, theta, smoothing):
        """The observations' weighted residuals, each point's albedo and F_tilde eliminated
        (paper's model, L = V), then the penalty; and F_tilde (3,)."""
        from .._vector import Vec3
        from ..estimation._albedo_map import projected_residuals
        from ..estimation._brdf import PAPER, design_columns
        from ..observations import ShadingSamples

        c, sigma = theta[:-1], theta[-1]
        camera = jnp.einsum("pmji,pj->pmi", self.rotation, self.normals(c))
        flat = lambda a, k: a[..., k].T.ravel()  # noqa: E731  views first, flattened
        normal = Vec3(*(flat(camera, k) for k in range(3)))
        view = Vec3(*(flat(self.view, k) for k in range(3)))
        size, views = normal.x.shape[0], camera.shape[1]
        samples = ShadingSamples(normal, view, view, jnp.ones(size), jnp.zeros((size, 3)))
        columns = tuple(c.reshape(views, -1) for c in design_columns(PAPER, sigma[None], samples))
        _, weights, residual = projected_residuals(columns, self.values, self.weight, 0)
        penalty = smoothing / 255 * self.spline.penalty(c)
        return jnp.concatenate([residual.ravel(), penalty]), weights[1]


def _levenberg_marquardt(points: _Points, sigma: float, smoothing: float, iterations: int, say):
    """(coefficients, sigma) by LM from 0 and the BnB's sigma; the Jacobian by forward mode
    in chunks of `_CHUNK` parameters. Returns theta, the cost before and after, the steps."""
    residual = jax.jit(lambda t: points.residuals(t, smoothing)[0])

    @jax.jit
    def jacobian_columns(theta, basis):
        return jax.vmap(jax.linearize(residual, theta)[1], in_axes=1, out_axes=1)(basis)

    theta = jnp.concatenate([jnp.zeros(points.spline.size), jnp.asarray([sigma])])
    n = theta.shape[0]
    eye = np.eye(n)
    r = np.asarray(residual(theta))
    first = cost = float(r @ r)
    damping, steps = 1e-3, 0
    for iteration in range(iterations):
        previous = cost
        # Written into one array (concatenating the blocks held the Jacobian twice).
        jacobian = np.empty((r.size, n))
        for start in range(0, n, _CHUNK):
            basis = np.pad(
                eye[:, start : start + _CHUNK], ((0, 0), (0, max(0, start + _CHUNK - n)))
            )
            block = np.asarray(jacobian_columns(theta, jnp.asarray(basis)))
            jacobian[:, start : start + _CHUNK] = block[:, : min(_CHUNK, n - start)]
        normal, gradient = jacobian.T @ jacobian, jacobian.T @ r
        while damping < 1e8:
            step = -np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-12), gradient)
            trial = theta + jnp.asarray(step)
            r_trial = np.asarray(residual(trial))
            if float(trial[-1]) > 0.01 and float(r_trial @ r_trial) < cost:
                theta, r, cost, damping, steps = (
                    trial,
                    r_trial,
                    float(r_trial @ r_trial),
                    damping / 3,
                    steps + 1,
                )
                break
            damping *= 10
        say(f"shading: iteration {iteration + 1}, cost {cost:.4g}, sigma {float(theta[-1]):.4f}")
        if previous - cost < RTOL * previous:  # (no step accepted: no decrease)
            break
    return theta, first, cost, steps


def refine_shape_by_shading(
    capture,
    *,
    smoothing: float | None = None,
    iterations: int | None = None,
    max_points: int | None = None,
    say=lambda message: None,
):
    """The capture with every frame's normals and depth corrected by one world height field
    fitted with sigma to the shading of every frame (see the module doc), and a report.
    The capture needs depth, normals and poses (world = a camera looking at the surface,
    as `reconstruct` writes them). `smoothing`, `iterations`, `max_points`: `SMOOTHING`,
    `ITERATIONS`, `MAX_POINTS` by default."""
    smoothing = SMOOTHING if smoothing is None else smoothing
    iterations = ITERATIONS if iterations is None else iterations
    max_points = MAX_POINTS if max_points is None else max_points
    from ..estimation._albedo_map import fit_brdf_map, track_shading

    started = time.perf_counter()
    depth = np.concatenate([f.depth[np.isfinite(f.depth)] for f in capture.frames])
    spacing = KNOT_FRACTION * float(np.median(depth))
    points = _Points(capture, spacing, max_points)
    start = fit_brdf_map(track_shading(points.shading))
    sigma0 = float(start.params[0])
    theta, before, after, steps = _levenberg_marquardt(points, sigma0, smoothing, iterations, say)
    coefficients = np.asarray(theta[:-1])
    frames, changes = [], []
    for frame in capture.frames:
        corrected, change = _corrected(
            frame, capture.camera, points.spline, points.base + coefficients, coefficients
        )
        frames.append(corrected)
        changes.append(change)
    report = {
        "model": "one world height-field correction (cubic B-spline) fitted with sigma to "
        "every frame's shading, albedo per point and F_tilde eliminated, light at the camera",
        "knot_spacing": spacing,
        "coefficients": points.spline.size,
        "smoothing": smoothing,
        "points": points.count,
        "sigma_before": sigma0,
        "sigma_after": float(theta[-1]),
        "cost_before": before,
        "cost_after": after,
        "steps": steps,
        "median_normal_change_deg": float(np.nanmedian(np.concatenate(changes))),
        "seconds": round(time.perf_counter() - started, 1),
    }
    return dataclasses.replace(capture, frames=tuple(frames)), report


def _corrected(frame, camera, spline: HeightSpline, surface, correction):
    """A frame whose normals are the world surface's (`surface` coefficients) where its
    pixels lie inside the spline's span, its depth moved by the `correction` along world z;
    and the angles (degrees) by which its normals turned."""
    rows, cols, ray, z, world = _world_pixels(frame, camera)
    index, value, d_x, d_y, inside = spline.basis(world[:, :2])
    rotation = frame.pose[:3, :3]
    hx, hy = np.sum(surface[index] * d_x, -1), np.sum(surface[index] * d_y, -1)
    before = frame.normals[rows, cols].astype(np.float64)
    turned = np.where(inside[:, None], _normals_from_slopes(hx, hy) @ rotation, before)
    dh = np.where(inside, np.sum(correction[index] * value, -1), 0)
    along = (ray @ rotation.T)[:, 2]  # the world z of a unit of depth
    safe = np.abs(along) > 1e-6
    normals, depth = frame.normals.copy(), frame.depth.copy()
    normals[rows, cols] = turned
    depth[rows, cols] = z + np.where(safe, dh / np.where(safe, along, 1), 0)
    change = np.degrees(np.arccos(np.clip(np.sum(turned * before, -1), -1, 1)))[inside]
    frame = dataclasses.replace(
        frame, normals=normals.astype(frame.normals.dtype), depth=depth.astype(frame.depth.dtype)
    )
    return frame, change
