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

How. LM's normal equations are assembled from their structure, not from a dense Jacobian:
with F_tilde given, a point's residuals depend on its own slopes (h_x, h_y) and sigma alone,
the slopes are linear in its 16 coefficients, and F_tilde* (eliminated) adds a rank-3 part
(`_Problem.gauss_newton_terms`, `_normal_equations`; equal to the dense Jacobian's to
rounding, tests/test_sfm.py). On tests/independent.py 640x512 x 8 seed 2 from its images
(6777 points, 1880 coefficients, 10 iterations): 436 s with the dense Jacobian (16 columns
a forward pass, J^T J at n^2 per residual), 14 s now, the same iterates to 12 digits.

Measured with 3 mm knots (`benchmarks/world_surface.py`: tests/independent.py 640x512 x 8
reconstructed from its images, then `fit_capture` with the albedo map; 2 mm, now the
default: `KNOT_FRACTION`): seed 1 normals 3.65 -> 1.11 degrees
median, sigma +14.2% -> +2.1%, F_tilde -43..-52% -> +2.3..+2.7% (another run, SfM's result
varying: 3.72 -> 0.95 degrees, +13.0% -> +1.5%, -46..-54% -> -0.4..0.0%); seed 2 normals
1.61 -> 0.29, sigma +7.3% -> -0.1%, F_tilde -40..-42% -> -4.0%; 110-140 s with the
dense Jacobian.

It fits the paper's light (at the camera): on a capture whose light is elsewhere it would
bend the shape to fit the wrong light (and hide the offset from the near-light model), so
`ctjax reconstruct` does it only when asked (`--shading`); `ctjax fit` on a capture with
images only, which fits that same model, does it by default (`--no-shading`).
"""

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array
from scipy import sparse

from .._errors import CaptureError
from ._height_spline import (
    HeightSpline,
    base_surface,
    normals_from_slopes,
    second_differences,
    world_pixels,
)
from ._shading_starts import GLOBAL_ITERATIONS, LIGHT_STARTS, distinct_starts, shading_starts

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
# A ridge on the correction, per knot spacing of height: the shading sees slopes only, and the
# penalty second differences, so nothing else holds the correction's constant part. Without
# it that part drifted under a near light (LM's damping falls as steps succeed): on `ctjax
# synth --stereo 5` 320x256 x 8 (seed 2, light at (4, -3, 0) mm) every frame's depth moved
# by -2.7%, against -0.03% before the refinement.
RIDGE = 1e-3
# LM stops once an iteration lowers the cost by less than this fraction: on `ctjax synth`
# 640x512 x 8 (seed 1) the cost reached 0.6063 at the second iteration and the other eight
# lowered it in the fifth digit (sigma 0.1967 -> 0.1966), 20 s of dense Jacobian each.
RTOL = 1e-4
MAX_POINTS = 8000
# A refinement that turns the normals by more than this (median, degrees) is not kept: on
# the synthetic captures it turns them by 0.5-0.7 degrees (SfM's are 0.5-4 off); on 12
# frames of the shared cholecystectomy video (sRGB, auto-exposure, a spot) by 53 (light at
# the camera) and 45 (near light), of the shared sinus sequence by 70 and 64. The height field
# alone, fused from their depth, already turns them by 7.8 and 38: these scenes are no
# height field over the first frame's image plane, and the shading bends it further.
MAX_NORMAL_CHANGE_DEG = 10.0


class _Points:
    """Tracked surface points (`shading`, `count` of them) under one height spline
    (`spline`, its coefficients fitted to the frames' depth: `base`), and the refinement's
    data on them (`problem`)."""

    def __init__(self, capture, spline_spacing: float, max_points: int, light=None, fit_light=True):
        from ..lights import ColocatedLight
        from ..observations import Observations

        tracks = Observations.of(capture).tracks(max_points=max_points)
        rotations = np.stack([f.pose[:3, :3] for f in capture.frames])
        shifts = np.stack([f.pose[:3, 3] for f in capture.frames])
        count = len(tracks)
        point = np.sum(tracks.corner_point * tracks.corner_weight[..., None], axis=2)
        normal = np.sum(tracks.corner_normal * tracks.corner_weight[..., None], axis=2)
        pixel = np.sum(tracks.corner_pixel * tracks.corner_weight[..., None], axis=2)
        rotation = rotations[np.where(tracks.observed, tracks.frame, 0)]
        world_normal = np.einsum("pmij,pmj->pmi", rotation, normal)
        # The sum of each point's world normals over its views: it must face the reference camera.
        facing = np.sum(np.where(tracks.observed[..., None], np.nan_to_num(world_normal), 0), 1)
        # A point's world position from its own view, or its first view where its own
        # pixel is clipped (the highlights' cores: seen elsewhere, the most informative).
        own_slot = (tracks.frame == tracks.anchor_frame[:, None]) & tracks.observed
        slot = np.where(own_slot.any(1), np.argmax(own_slot, 1), np.argmax(tracks.observed, 1))
        frame = tracks.frame[np.arange(count), slot]
        world = np.einsum("pij,pj->pi", rotations[frame], point[np.arange(count), slot])
        world += shifts[frame]
        keep = (np.linalg.norm(facing, axis=-1) > 0) & tracks.observed[np.arange(count), slot]
        keep &= np.all(np.isfinite(world), -1) & (facing[:, 2] < 0)
        self.count = int(keep.sum())
        self.spline = HeightSpline.covering(world[keep, :2], spline_spacing)
        index, _, d_x, d_y, _ = self.spline.basis(world[keep, :2])
        self.base = base_surface(capture, self.spline)
        base = self.base[index]
        observed = tracks.observed[keep][..., None]
        # Unobserved slots: a point straight ahead at the median depth (finite, weight 0).
        ahead = [0.0, 0.0, float(np.nanmedian(point[keep][..., 2]))]
        camera_point = np.where(observed, np.nan_to_num(point[keep]), ahead)
        view = -camera_point / np.maximum(
            np.linalg.norm(camera_point, axis=-1, keepdims=True), 1e-9
        )
        light = ColocatedLight() if light is None else light
        self.problem = _Problem(
            *map(
                jnp.asarray,
                (
                    index,
                    d_x,
                    d_y,
                    np.stack([np.sum(base * d_x, -1), np.sum(base * d_y, -1)], -1),
                    rotation[keep],
                    view,
                    camera_point,
                    np.where(observed, np.nan_to_num(pixel[keep]), 0.0),
                    np.transpose(np.nan_to_num(tracks.values[keep]), (2, 1, 0)),
                    np.where(tracks.observed[keep], tracks.weight[keep], 0).T,
                ),
            ),
            light,
            self.spline.shape,
            _LightParameters.of(light, fit_light),
        )
        self.shading = tracks.select(np.nonzero(keep)[0])


@dataclasses.dataclass(frozen=True)
class _LightParameters:
    """The light's free parameters (`ctjax.fitting.free_parameters`: for a `PointLight` its
    position, for a spot its exponent), the refinement's global unknowns beside sigma, as
    one flat vector of unconstrained values."""

    parameters: tuple
    shapes: tuple

    @classmethod
    def of(cls, light, fitted: bool = True) -> "_LightParameters":
        from ..fitting import free_parameters

        parameters = tuple(free_parameters(light)) if fitted else ()
        return cls(parameters, tuple(tuple(np.shape(p.get(light))) for p in parameters))

    @property
    def size(self) -> int:
        return sum(int(np.prod(shape)) for shape in self.shapes)

    def vector(self, light) -> np.ndarray:
        from ..fitting import unconstrained

        values = unconstrained(light, list(self.parameters))
        return np.concatenate([np.ravel(np.asarray(v, float)) for v in values] + [np.zeros(0)])

    def light(self, light, vector):
        """`light` with its free parameters set from the unconstrained `vector`."""
        from ..fitting import constrained

        values, at = [], 0
        for shape in self.shapes:
            size = int(np.prod(shape))
            values.append(vector[at : at + size].reshape(shape))
            at += size
        return constrained(light, list(self.parameters), values)


class _Problem(eqx.Module):
    """The refinement's data, passed to its compiled functions as arguments (not baked into
    them as constants): the spline's basis at the points (`index`, `d_x`, `d_y`, (P, 16)),
    the base surface's slopes there (P, 2), each observation's rotation (camera to world,
    (P, M, 3, 3)), view direction, camera-frame point (mm) and pixel (P, M, 3 / 2), the
    values (C, M, P) and weights (M, P); the light, whose free parameters (`free`) are
    global unknowns beside sigma: theta = (coefficients, sigma, the light's)."""

    index: Array
    d_x: Array
    d_y: Array
    slopes: Array
    rotation: Array
    view: Array
    point: Array
    pixel: Array
    values: Array
    weight: Array
    light: eqx.Module
    grid: tuple[int, int] = eqx.field(static=True)
    free: _LightParameters = eqx.field(static=True)

    @property
    def globals_count(self) -> int:
        """sigma and the light's free parameters: the unknowns every observation shares."""
        return 1 + self.free.size

    def split(self, theta):
        """theta -> (coefficients, globals)."""
        return theta[: -self.globals_count], theta[-self.globals_count :]

    def slopes_of(self, c):
        """Each point's height-field slopes (h_x, h_y) with correction coefficients `c`."""
        return (
            self.slopes[:, 0] + jnp.sum(c[self.index] * self.d_x, -1),
            self.slopes[:, 1] + jnp.sum(c[self.index] * self.d_y, -1),
        )

    def columns(self, hx, hy, g):
        """The paper's lobes' values for unit weight at every observation under the light
        (sigma = g[0], the light's free parameters g[1:]), (views, P) each."""
        from .._vector import Vec3
        from ..estimation._brdf import PAPER, design_columns
        from ..observations import ShadingSamples

        camera = jnp.einsum("pmji,pj->pmi", self.rotation, normals_from_slopes(hx, hy, jnp))
        flat = lambda a, k: a[..., k].T.ravel()  # noqa: E731  views first, flattened
        normal, view, point = (
            Vec3(*(flat(a, k) for k in range(3))) for a in (camera, self.view, self.point)
        )
        light = self.free.light(self.light, g[1:])
        pixel = jnp.stack([flat(self.pixel, 0), flat(self.pixel, 1)], -1)
        direction, irradiance = jax.vmap(light.illuminate)(point, view, pixel)
        size, views = normal.x.shape[0], camera.shape[1]
        samples = ShadingSamples(normal, direction, view, irradiance, jnp.zeros((size, 3)))
        return tuple(c.reshape(views, -1) for c in design_columns(PAPER, g[:1], samples))

    def residuals(self, theta, smoothing, ridge=0.0):
        """The observations' weighted residuals, each point's albedo and F_tilde eliminated
        (paper's model), then the penalty (second differences, and `ridge` times the
        coefficients); and F_tilde (3,)."""
        from ..estimation._variable_projection import projected_residuals

        c, g = self.split(theta)
        columns = self.columns(*self.slopes_of(c), g)
        _, weights, residual = projected_residuals(columns, self.values, self.weight, 0)
        penalty = smoothing / 255 * second_differences(self.grid, c)
        return jnp.concatenate([residual.ravel(), penalty, ridge * c]), weights[1]

    def gauss_newton_terms(self, theta):
        """The data residuals' Gauss-Newton terms over h = (every point's h_x, h_y; g, the
        G global unknowns: sigma and the light's).

        With F_tilde given, a point's residuals depend on its own slopes and g alone (its
        albedo is eliminated from its own observations): that Jacobian A is a 2x2 block per
        point plus G global columns. F_tilde* (eliminated) depends on all: the projected
        residuals' Jacobian is A + U W^T with U = dr/dF_tilde (R, 3) and W = dF_tilde*/dh
        (3 columns), exactly (chain rule). Returns per point the sums over its rows of A's
        products (A^T A's blocks, A^T U, A^T r), and U^T U, U^T r, W, and the cost:
        everything J^T J and J^T r need, in one pass of 5 + G tangents and 3 cotangents
        instead of a dense (R, n) Jacobian."""
        from ..estimation._variable_projection import projected_residuals, residuals_given_weights

        c, g = self.split(theta)
        hx, hy = self.slopes_of(c)
        count, dtype = self.globals_count, theta.dtype

        def brdf_weights(hx, hy, g):
            columns = self.columns(hx, hy, g)
            return projected_residuals(columns, self.values, self.weight, 0)[1]

        weights, pullback = jax.vjp(lambda *h: brdf_weights(*h)[1], hx, hy, g)
        w_x, w_y, w_g = jax.vmap(pullback)(jnp.eye(3, dtype=dtype))

        def local(hx, hy, g, f):
            columns = self.columns(hx, hy, g)
            return residuals_given_weights(columns, self.values, self.weight, jnp.stack([f, f]))

        # Tangent directions: h_x, h_y (every point at once: each point's rows depend on its
        # own), each global, each F_tilde channel.
        k = 2 + count + 3
        pick = lambda i: jnp.zeros(k, dtype).at[i].set(1)  # noqa: E731
        tangents = (
            jnp.outer(pick(0), jnp.ones_like(hx)),
            jnp.outer(pick(1), jnp.ones_like(hx)),
            jnp.eye(k, dtype=dtype)[:, 2 : 2 + count],
            jnp.eye(k, dtype=dtype)[:, 2 + count :],
        )
        primals = (hx, hy, g, weights)
        r, derivatives = jax.vmap(lambda *t: jax.jvp(local, primals, t), out_axes=(None, 0))(
            *tangents
        )
        a_x, a_y = derivatives[0], derivatives[1]
        a_g, u = derivatives[2 : 2 + count], derivatives[2 + count :]
        per_point = lambda x, y: jnp.sum(x * y, axis=(-3, -2))  # noqa: E731  (C, M, P) -> (P,)
        total = lambda x, y: jnp.sum(x * y, axis=(-3, -2, -1))  # noqa: E731
        return {
            "at_a": jnp.stack([per_point(a_x, a_x), per_point(a_x, a_y), per_point(a_y, a_y)]),
            "at_g": jnp.stack([per_point(a_x[None], a_g), per_point(a_y[None], a_g)]),  # (2,G,P)
            "gt_g": total(a_g[:, None], a_g[None]),  # (G, G)
            "at_u": jnp.stack([per_point(a_x[None], u), per_point(a_y[None], u)]),  # (2, 3, P)
            "gt_u": total(a_g[:, None], u[None]),  # (G, 3)
            "at_r": jnp.stack([per_point(a_x, r), per_point(a_y, r)]),
            "gt_r": total(a_g, r[None]),  # (G,)
            "ut_u": total(u[:, None], u[None]),  # (3, 3)
            "ut_r": total(u, r[None]),  # (3,)
            "w": (w_x, w_y, w_g),  # (3, P), (3, P), (3, G)
            "cost": jnp.sum(r * r),
        }


def _slope_map(points: _Points) -> sparse.csr_matrix:
    """S (2P + G, n): h = (h_x, h_y, g) is affine in theta = (coefficients, g)."""
    count, globals_count = points.count, points.problem.globals_count
    n = points.spline.size + globals_count
    index = np.asarray(points.problem.index)
    rows = np.concatenate(
        [np.repeat(np.arange(count), 16), np.repeat(np.arange(count), 16) + count]
    )
    cols = np.concatenate([index.ravel(), index.ravel()])
    values = np.concatenate([np.ravel(points.problem.d_x), np.ravel(points.problem.d_y)])
    rows = np.concatenate([rows, 2 * count + np.arange(globals_count)])
    cols = np.concatenate([cols, n - globals_count + np.arange(globals_count)])
    values = np.concatenate([values, np.ones(globals_count)])
    return sparse.csr_matrix((values, (rows, cols)), (2 * count + globals_count, n))


def _normal_equations(terms, slope_map):
    """J^T J (n, n) and J^T r (n,) of the data residuals from `gauss_newton_terms`."""
    t = jax.tree_util.tree_map(np.asarray, terms)
    count = t["at_a"].shape[1]
    xx, xy, yy = t["at_a"]
    p, q = np.arange(count), np.arange(count) + count
    rows, cols = np.concatenate([p, p, q, q]), np.concatenate([p, q, p, q])
    blocks = sparse.csr_matrix(
        (np.concatenate([xx, xy, xy, yy]), (rows, cols)), (2 * count, 2 * count)
    )
    across = sparse.csr_matrix(np.concatenate([t["at_g"][0].T, t["at_g"][1].T]))  # (2P, G)
    at_a = sparse.bmat([[blocks, across], [across.T, sparse.csr_matrix(t["gt_g"])]]).tocsr()
    normal = (slope_map.T @ at_a @ slope_map).toarray()
    stack = lambda x, y, g: np.concatenate([x, y, g])  # noqa: E731  h-space
    at_u = slope_map.T @ stack(t["at_u"][0].T, t["at_u"][1].T, t["gt_u"])  # (n, 3)
    w = slope_map.T @ stack(t["w"][0].T, t["w"][1].T, t["w"][2].T)  # (n, 3)
    normal += at_u @ w.T + w @ at_u.T + w @ t["ut_u"] @ w.T
    gradient = slope_map.T @ stack(*t["at_r"], t["gt_r"]) + w @ t["ut_r"]
    return normal, gradient


def _levenberg_marquardt(
    points: _Points, sigma: float, smoothing: float, iterations: int, say, unit=("mm", 1.0)
):
    """theta = (coefficients, sigma, the light's free parameters) by LM from a flat
    correction and the best (sigma, light) starts (`_starts`; `unit`: the capture's length
    unit and median depth, for the light's starts), on the normal equations assembled from
    `gauss_newton_terms` (the penalty's own are constant). Returns theta, the cost before
    and after, the steps."""
    ridge = RIDGE / points.spline.spacing
    residual = jax.jit(lambda problem, t: problem.residuals(t, smoothing, ridge)[0])
    terms_at = jax.jit(lambda problem, t: problem.gauss_newton_terms(t))
    slope_map = _slope_map(points)
    size = points.spline.size
    penalty = points.spline.penalty_matrix() * (smoothing / 255)
    penalty_normal = np.zeros((slope_map.shape[1],) * 2)
    penalty_normal[:size, :size] = (penalty.T @ penalty).toarray()
    penalty_normal[:size, :size] += ridge**2 * np.eye(size)

    def descend(theta, cost, free, iterations, label):
        """LM over theta[free] alone; the rest held."""
        damping, steps = 1e-3, 0
        for iteration in range(iterations):
            previous = cost
            normal, gradient = _normal_equations(terms_at(points.problem, theta), slope_map)
            normal = (normal + penalty_normal)[free, free]
            gradient = (gradient + penalty_normal @ np.asarray(theta))[free]
            while damping < 1e8:
                step = np.linalg.solve(
                    normal + damping * np.diag(np.diag(normal) + 1e-12), gradient
                )
                trial = theta.at[free].add(-jnp.asarray(step))
                r_trial = np.asarray(residual(points.problem, trial))
                if float(trial[size]) > 0.01 and float(r_trial @ r_trial) < cost:
                    theta, cost = trial, float(r_trial @ r_trial)
                    damping, steps = damping / 3, steps + 1
                    break
                damping *= 10
            sigma = float(theta[size])
            say(f"shading: {label} {iteration + 1}, cost {cost:.4g}, sigma {sigma:.4f}")
            if previous - cost < RTOL * previous:  # (no step accepted: no decrease)
                break
        return theta, cost, steps

    starts = shading_starts(points, sigma, residual, *unit)
    first, theta = starts[0]
    cost, steps = first, 0
    if points.problem.free.size:
        held = slice(size, None)
        distinct = distinct_starts(starts, size, LIGHT_STARTS)
        found = [descend(t, c, held, GLOBAL_ITERATIONS, "light") for c, t in distinct]
        theta, cost, steps = min(found, key=lambda f: f[1])
    theta, cost, more = descend(theta, cost, slice(None), iterations, "iteration")
    return theta, first, cost, steps + more


def refine_shape_by_shading(
    capture,
    *,
    light=None,
    fit_light: bool = True,
    smoothing: float | None = None,
    iterations: int | None = None,
    max_points: int | None = None,
    say=lambda message: None,
):
    """The capture with every frame's normals and depth corrected by one world height field
    fitted with sigma to the shading of every frame (see the module doc), and a report.
    The capture needs depth, normals and poses (world = a camera looking at the surface,
    as `reconstruct` writes them). `light`: the laparoscope's light (`ctjax.lights`; the
    paper's, at the camera, by default); with `fit_light` its free parameters (a
    `LensPlaneLight`'s offset, a `PointLight`'s position, a spot's exponent) are fitted
    jointly with the surface, from their given values (the report's `light`). `smoothing`,
    `iterations`, `max_points`: `SMOOTHING`, `ITERATIONS`, `MAX_POINTS` by default. A
    refinement that turns the normals by more than `MAX_NORMAL_CHANGE_DEG` (median) is not
    kept: the capture comes back as it was and the report's `rejected` says why."""
    smoothing = SMOOTHING if smoothing is None else smoothing
    iterations = ITERATIONS if iterations is None else iterations
    max_points = MAX_POINTS if max_points is None else max_points
    from .._units import length_unit_of
    from ..estimation._branch_and_bound_map import fit_brdf_map, track_shading

    started = time.perf_counter()
    missing = [f.name for f in capture.frames if f.depth is None or f.pose is None]
    if missing:
        raise CaptureError(
            f"{capture.root}: the shading refinement needs every frame's depth, normals and "
            f"pose (ctjax reconstruct); {', '.join(missing)} lack them"
        )
    depth = np.concatenate([f.depth[np.isfinite(f.depth)] for f in capture.frames])
    spacing = KNOT_FRACTION * float(np.median(depth))
    points = _Points(capture, spacing, max_points, light, fit_light)
    start = fit_brdf_map(track_shading(points.shading))
    sigma0 = float(start.params[0])
    unit = (length_unit_of(capture), float(np.median(depth)))
    theta, before, after, steps = _levenberg_marquardt(
        points, sigma0, smoothing, iterations, say, unit
    )
    problem = points.problem
    coefficients, g = (np.asarray(x) for x in problem.split(theta))
    frames, changes = [], []
    for frame in capture.frames:
        corrected, change = _corrected(
            frame, capture.camera, points.spline, points.base + coefficients, coefficients
        )
        frames.append(corrected)
        changes.append(change)
    report = {
        "model": "one world height-field correction (cubic B-spline) fitted with sigma to "
        "every frame's shading, albedo per point and F_tilde eliminated, " + _light_words(problem),
        "knot_spacing": spacing,
        "coefficients": points.spline.size,
        "smoothing": smoothing,
        "points": points.count,
        "sigma_before": sigma0,
        "sigma_after": float(g[0]),
        "cost_before": before,
        "cost_after": after,
        "steps": steps,
        "median_normal_change_deg": float(np.nanmedian(np.concatenate(changes))),
        "seconds": round(time.perf_counter() - started, 1),
    }
    if problem.free.size:
        fitted = problem.free.light(problem.light, jnp.asarray(g[1:]))
        report["light"] = {
            p.name: np.asarray(p.get(fitted)).tolist() for p in problem.free.parameters
        }
        if hasattr(fitted, "position_mm"):  # (x, y, z) whatever the light fits of it
            report["light"]["position_mm"] = np.asarray(fitted.position_mm).tolist()
        # Positions are in the capture's length unit, whatever the field is called.
        report["light"]["length_unit"] = unit[0]
    if report["median_normal_change_deg"] > MAX_NORMAL_CHANGE_DEG:
        report["rejected"] = (
            f"the shading refinement turned the normals by "
            f"{report['median_normal_change_deg']:.1f} degrees (median), more than "
            f"{MAX_NORMAL_CHANGE_DEG:g}: its model (one height field over the first frame's "
            "image plane, the paper's BRDF) does not explain these frames' shading (a scene "
            "that is no such height field, or an effect the model lacks); shape kept"
        )
        return capture, report
    return dataclasses.replace(capture, frames=tuple(frames)), report


def _light_words(problem: _Problem) -> str:
    name = type(problem.light).__name__
    if not problem.free.size:
        return f"light {name} held"
    names = ", ".join(p.name for p in problem.free.parameters)
    return f"light {name} fitted jointly ({names})"


def _corrected(frame, camera, spline: HeightSpline, surface, correction):
    """A frame whose normals are the world surface's (`surface` coefficients) where its
    pixels lie inside the spline's span, its depth moved by the `correction` along world z;
    and the angles (degrees) by which its normals turned."""
    rows, cols, ray, z, world = world_pixels(frame, camera)
    index, value, d_x, d_y, inside = spline.basis(world[:, :2])
    rotation = frame.pose[:3, :3]
    hx, hy = np.sum(surface[index] * d_x, -1), np.sum(surface[index] * d_y, -1)
    before = frame.normals[rows, cols].astype(np.float64)
    turned = np.where(inside[:, None], normals_from_slopes(hx, hy) @ rotation, before)
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
