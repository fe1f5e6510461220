"""The paper's per-pixel light field (section 5, eqs. 7-8).

Per pixel of S-bar, the light's direction L is fitted by Levenberg-Marquardt (on autodiff
Jacobians of the renderer's physics, `BRDF.radiance`), vmapped over pixels and jitted, with
the BRDF (rho~, F~, sigma) estimated first: optimistix's LM (`solve_pixels`, the reference
engine) or the same method written out for the 2 unknowns (`solve_pixels_closed_form`, the
"closed-form" engine, ~10x faster on CPU for the same directions). The solve starts from
the boundary condition on the specular set S and propagates outwards, band after band of
pixels, each starting from its already-solved neighbours; a cubic B-spline is then fitted
over the image, and every pixel is solved once more against it, giving a smooth field
(`LightField`) that the renderer evaluates at any pixel.

Conventions and choices, all measured on synthetic captures (see `benchmarks/light_lm.py`):

- **Boundary value on S.** The paper writes L = (0, 0, 1) on S: the optical axis, in a frame
  whose z points back towards the camera. With ctjax's camera frame (z forward, directions
  pointing away from the surface), the paper's assumption "the light is co-located with the
  camera on S" is L = V, the pixel's view direction (what `ColocatedLight` returns), which
  differs from the optical axis by the pixel's ray angle (up to ~30 degrees in the corners):
  L = V is the boundary value used here.
- **Angles.** `theta`, `phi` are eq. (7)'s tilt and slant in the paper's frame, which is
  ctjax's camera frame turned by 180 degrees about x (x right, y up, z towards the viewer):
  `L = (sin phi cos theta, -sin phi sin theta, -cos phi)` in ctjax's frame. They are
  reported, but LM works in tangent-plane coordinates around each pixel's start direction:
  eq. (7) is singular at phi = 0, which is exactly the boundary value near the image centre
  (the Jacobian in theta vanishes there). The model is the same, a unit direction per pixel.
- **Well-posedness.** One RGB value gives essentially one equation for two angles (the
  diffuse term sees only N.L; the specular term matters near highlights only), so a valley
  of equally good directions remains and noise picks a point in it. Two additions, inside
  the paper's model: (1) every calibration frame at once: the light is rigid with the
  camera, so a pixel's L is shared by the frames, each of which adds a shading equation with
  another normal; (2) a smoothness prior: extra residuals `(L - L_prior) / prior_deg`
  (a departure of `prior_deg` degrees costs as much as one 8-bit level), towards the mean
  of the solved neighbours while propagating, and towards the spline afterwards.
- **Spline.** A least-squares cubic B-spline on a coarse uniform knot grid, with a small
  second-difference penalty that fills holes (pixels without data), fitted to the three
  components of L - V (not to theta and phi, which wrap around and are singular at phi = 0,
  as `LightField` does for interpolation); normalised after evaluation.
"""

import dataclasses
import itertools
import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from scipy import ndimage

from .._convert import cast_floating
from .._errors import CtjaxError
from .._geometry import points_from_depth
from .._typing import Array, Float
from .._vector import Vec3, tangent_direction
from ..diagnostics._diagnose import noise_floor_levels, split_frames
from ..estimation._capture_fit import MaskOptions, capture_sets
from ..estimation._samples import view_directions
from ..fitting import (
    FitResult,
    ShadingModel,
    capture_samples,
    fit_model,
    paper_model,
    pixel_columns,
    pixel_predict,
    rmse_levels,
    roughness_variants,
    strongly_typed,
)
from ..fitting._samples import usable_mask
from ..io import Capture
from ..lights import ColocatedLight, InverseSquare, LightField, angles_from_direction
from ..lobes import BRDF

# ctjax's camera frame -> the paper's (x right, y up, z towards the viewer).
_PAPER_FRAME = np.array([1.0, -1.0, -1.0])
# Propagation: pixels are solved in bands of distance (px) from S, each band starting from
# the solved pixels inside it; widths double, so a 640x480 image takes ~10 batched solves.
_FIRST_BAND_PX = 3.0
# Every batched solve has this many pixels (the last batch padded): one compilation.
_BATCH = 4096
# `calibrate_light_field`'s per-pixel solvers: `solve_pixels` with optimistix's LM (the
# reference), `solve_pixels_closed_form`.
_ENGINES = ("optimistix", "closed-form")


def paper_angles(directions: Float[Array, "... 3"]) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (7)'s (theta, phi) of unit directions in ctjax's camera frame (radians).

    theta in [-pi, pi] (tilt), phi in [0, pi] (slant from the paper's z, the optical axis
    pointing back towards the camera; light in front of the surface: phi < pi / 2).
    """
    theta, phi = angles_from_direction(jnp.asarray(directions) * _PAPER_FRAME)
    return np.asarray(theta), np.asarray(phi)


def directions_from_paper_angles(theta, phi) -> np.ndarray:
    """Inverse of `paper_angles`: unit directions (..., 3) in ctjax's camera frame."""
    theta, phi = np.asarray(theta, float), np.asarray(phi, float)
    paper = np.stack([np.sin(phi) * np.cos(theta), np.sin(phi) * np.sin(theta), np.cos(phi)], -1)
    return paper * _PAPER_FRAME


# ---------------------------------------------------------------------------------------
# The per-pixel problem (eq. 8), for one pixel; batches come from vmap.


class PixelProblem(eqx.Module):
    """One pixel's data over F frames (a batch of pixels under vmap): the unit view
    direction V (camera frame; the same in every frame, it depends on the pixel only), the
    unit normal and measured linear RGB in each frame, a weight per frame (1 where the
    pixel is in S-bar in that frame, else 0), the start direction and the prior direction."""

    view: Vec3
    normal: Vec3  # components (F,)
    values: Float[Array, "F 3"]
    weight: Float[Array, " F"]
    irradiance: Float[Array, " F"]
    start: Vec3
    prior: Vec3


def pixel_residuals(y, problem: PixelProblem, brdf: BRDF, prior_scale) -> Float[Array, " R"]:
    """Eq. (8)'s residuals of one pixel in 8-bit levels, every frame (F x 3), then the
    prior's three (`(L - L_prior) * prior_scale`, `prior_scale` = 1 / prior_deg in 1/rad)."""
    light = tangent_direction(problem.start, y)

    def one_frame(normal, values, weight, irradiance):
        predicted = irradiance * brdf.radiance(normal, light, problem.view)
        return 255 * weight * (predicted - values)

    shading = jax.vmap(one_frame)(
        problem.normal, problem.values, problem.weight, problem.irradiance
    )
    prior = (light - problem.prior).to_array() * prior_scale
    return jnp.concatenate([shading.reshape(-1), prior])


class PixelSolution(eqx.Module):
    """Per pixel: the unit light direction (camera frame), the solver's status (an
    `optx.RESULTS` code, 0 = successful), its number of steps and the data's RMSE (levels)."""

    direction: Float[Array, "P 3"]
    result: Array
    steps: Array
    rmse: Float[Array, " P"]


@eqx.filter_jit
def solve_pixels(
    problems: PixelProblem,
    brdf: BRDF,
    prior_scale: float,
    solver: optx.AbstractLeastSquaresSolver,
    max_steps: int,
) -> PixelSolution:
    """Eq. (8) per pixel by `solver` (e.g. `optx.LevenbergMarquardt`), vmapped over the
    pixels of `problems` (a batch of `PixelProblem`s), from their start directions."""

    def one(problem):
        y0 = jnp.zeros(2, problem.values.dtype)
        solution = optx.least_squares(
            lambda y, _: pixel_residuals(y, problem, brdf, prior_scale),
            solver,
            y0,
            max_steps=max_steps,
            throw=False,
        )
        light = tangent_direction(problem.start, solution.value)
        rmse = _data_rmse(solution.value, problem, brdf)
        return light.to_array(), solution.result._value, solution.stats["num_steps"], rmse

    direction, result, steps, rmse = jax.vmap(one)(problems)
    return PixelSolution(direction, result, steps, rmse)


def _data_rmse(y, problem: PixelProblem, brdf: BRDF):
    """One pixel's RMSE (levels) of the shading residuals at `y`, over its observed values."""
    residual = pixel_residuals(y, problem, brdf, 0.0)
    frames = problem.values.shape[0]
    count = 3 * jnp.maximum(jnp.sum(problem.weight), 1)
    return jnp.sqrt(jnp.sum(residual[: 3 * frames] ** 2) / count)


# The closed-form engine's codes, in `optx.RESULTS`' numbering (what `status_counts` reads).
_SUCCESSFUL = int(optx.RESULTS.successful._value)
_MAX_STEPS = int(optx.RESULTS.nonlinear_max_steps_reached._value)  # as optx.least_squares
_NONFINITE = int(optx.RESULTS.nonfinite._value)
# Marquardt damping (relative to the diagonal of J^T J): start, factors on accepting and on
# rejecting a step, and a ceiling (no overflow in float32 when every trial is rejected).
_DAMPING = (1e-3, 1 / 3, 4.0, 1e10)


@eqx.filter_jit
def solve_pixels_closed_form(
    problems: PixelProblem,
    brdf: BRDF,
    prior_scale: float,
    iterations: int,
    rtol: float = 1e-4,
    atol: float = 1e-6,
) -> PixelSolution:
    """Eq. (8) per pixel by a batched Levenberg-Marquardt written out for 2 unknowns, the
    tangent-plane coordinates of L around each pixel's start direction.

    Every pixel runs exactly `iterations` iterations (no loop condition: under vmap the
    slowest pixel would set the time anyway). Per iteration: the residuals and their
    Jacobian (`jax.jacfwd` of `pixel_residuals`, 2 columns), the damped normal equations
    `(J^T J + lambda diag(J^T J)) dy = -J^T r` solved by the explicit 2x2 inverse, and the
    trial step accepted if it lowers the cost (then lambda / 3), else rejected (lambda x 4).
    A trial whose cost is not finite (e.g. an underflowing lobe) is rejected, and Jacobian
    entries that are not finite count as 0, so no NaN reaches the solution.

    Same result as `solve_pixels`: `result` is an `optx.RESULTS` code, `successful` where
    the last iteration's undamped Gauss-Newton step is within `atol + rtol * |y|` (max
    norms, as optimistix's Cauchy test on y) or would lower the cost by at most `rtol` of
    it (a gradient test: a valley flat to rounding, e.g. in float32),
    `nonlinear_max_steps_reached` (as `optx.least_squares` out of steps) where neither
    holds, and `nonfinite` where the cost at the solution is not finite (such a pixel keeps
    its start direction); `steps` counts the accepted steps. Works in the dtype of
    `problems` (the BRDF is cast to it), float32 or float64.
    """
    d0, shrink, grow, ceiling = _DAMPING

    dtype = problems.values.dtype
    # The BRDF in the data's precision too: every iterate, step and cost in `dtype`.
    brdf = cast_floating(brdf, dtype)

    def one(problem):
        def residual(y):
            return pixel_residuals(y, problem, brdf, prior_scale)

        def cost(y):
            r = residual(y)
            return r @ r

        def step(_, carry):
            y, damping, accepted, _ = carry
            r = residual(y)
            jac = jnp.nan_to_num(jax.jacfwd(residual)(y), nan=0.0, posinf=0.0, neginf=0.0)
            a, b, d = jac[:, 0] @ jac[:, 0], jac[:, 0] @ jac[:, 1], jac[:, 1] @ jac[:, 1]
            g0, g1 = jac[:, 0] @ r, jac[:, 1] @ r

            def solve(a, d):
                det = a * d - b * b
                safe = jnp.where(det > 0, det, 1)
                dy = -jnp.stack([d * g0 - b * g1, a * g1 - b * g0]) / safe
                ok = (det > 0) & jnp.all(jnp.isfinite(dy))
                return jnp.where(ok, dy, 0), ok

            # The damped step (the trial), and the Gauss-Newton one for the convergence test
            # (the damped one where J^T J is singular, e.g. without a prior).
            dy, _ = solve(a * (1 + damping), d * (1 + damping))
            newton, regular = solve(a, d)
            newton = jnp.where(regular, newton, dy)
            trial = cost(y + dy)
            better = jnp.isfinite(trial) & (trial < r @ r)
            y = jnp.where(better, y + dy, y)
            damping = jnp.minimum(jnp.where(better, damping * shrink, damping * grow), ceiling)
            # Converged: the Gauss-Newton step is small, or would hardly lower the cost (its
            # model's decrease is -g . newton), e.g. along a valley flat to rounding.
            small = (jnp.max(jnp.abs(newton)) <= atol + rtol * jnp.max(jnp.abs(y))) | (
                -(g0 * newton[0] + g1 * newton[1]) <= rtol * (r @ r)
            )
            return y, damping, accepted + better, small

        y, _, accepted, small = jax.lax.fori_loop(
            0,
            iterations,
            step,
            (jnp.zeros(2, dtype), jnp.asarray(d0, dtype), jnp.asarray(0), jnp.asarray(False)),
        )
        finite = jnp.isfinite(cost(y)) & jnp.all(jnp.isfinite(y))
        y = jnp.where(finite, y, 0)
        code = jnp.where(finite, jnp.where(small, _SUCCESSFUL, _MAX_STEPS), _NONFINITE)
        light = tangent_direction(problem.start, y)
        return light.to_array(), code, accepted, _data_rmse(y, problem, brdf)

    direction, result, steps, rmse = jax.vmap(one)(problems)
    return PixelSolution(direction, result, steps, rmse)


# ---------------------------------------------------------------------------------------
# Batches of pixels from the capture (NumPy side).


@dataclasses.dataclass
class _Observations:
    """Every calibration frame's data at every pixel, (H, W, F, ...), and the view (H, W, 3)."""

    view: np.ndarray
    normal: np.ndarray  # (H, W, F, 3), 0 where unobserved
    values: np.ndarray  # (H, W, F, 3)
    weight: np.ndarray  # (H, W, F)
    irradiance: np.ndarray  # (H, W, F)


def _observations(capture: Capture, frames: list[int], sets, falloff, dtype) -> _Observations:
    camera = capture.camera
    rows, cols = np.mgrid[0 : camera.height, 0 : camera.width]
    view = view_directions(camera, rows.astype(float), cols.astype(float))
    normal, values, weight, irradiance = [], [], [], []
    for index in frames:
        frame = capture.frames[index]
        observed = usable_mask(frame) & ~sets[index].specular & ~sets[index].saturated
        normal.append(np.where(observed[..., None], np.nan_to_num(frame.normals), [0, 0, -1]))
        values.append(np.where(observed[..., None], frame.image, 0))
        weight.append(observed)
        point = points_from_depth(camera, np.where(observed, frame.depth, 1.0))
        factor = np.ones(observed.shape)
        for effect in falloff:
            factor = factor * np.asarray(effect(Vec3.from_array(point)))
        irradiance.append(factor)
    stack = lambda parts: np.stack(parts, axis=2).astype(dtype)  # noqa: E731
    return _Observations(
        view.astype(dtype), stack(normal), stack(values), stack(weight), stack(irradiance)
    )


def _problems(obs: _Observations, index, start, prior) -> PixelProblem:
    """A batch of pixels (flat indices), padded to `_BATCH` by repeating the last."""
    index = np.concatenate([index, np.full(_BATCH - len(index), index[-1])])
    height, width = obs.view.shape[:2]
    flat = lambda a: a.reshape(height * width, *a.shape[2:])[index]  # noqa: E731
    vec = lambda a: Vec3.from_array(jnp.asarray(a))  # noqa: E731
    return PixelProblem(
        vec(flat(obs.view)),
        vec(flat(obs.normal)),
        jnp.asarray(flat(obs.values)),
        jnp.asarray(flat(obs.weight)),
        jnp.asarray(flat(obs.irradiance)),
        vec(start[index].astype(obs.view.dtype)),
        vec(prior[index].astype(obs.view.dtype)),
    )


def _solve(obs, index, start, prior, brdf, solve):
    """Solve the pixels `index` (flat) in batches by `solve(problems, brdf)`; start and prior
    are (H*W, 3)."""
    out = {k: [] for k in ("direction", "result", "steps", "rmse")}
    for lo in range(0, len(index), _BATCH):
        part = index[lo : lo + _BATCH]
        solution = solve(_problems(obs, part, start, prior), brdf)
        for key in out:
            out[key].append(np.asarray(getattr(solution, key))[: len(part)])
    return {k: np.concatenate(v) for k, v in out.items()}


def _neighbour_mean(directions: np.ndarray, solved: np.ndarray, radius: int = 2) -> np.ndarray:
    """Per pixel, the normalised mean of the solved directions within `radius` px, or the
    nearest solved pixel's direction where none is that close. (H, W, 3)."""
    size = 2 * radius + 1
    weight = ndimage.uniform_filter(solved.astype(float), size, mode="constant")
    total = np.stack(
        [
            ndimage.uniform_filter(np.where(solved, directions[..., k], 0), size, mode="constant")
            for k in range(3)
        ],
        -1,
    )
    _, (near_r, near_c) = ndimage.distance_transform_edt(~solved, return_indices=True)
    nearest = directions[near_r, near_c]
    mean = np.where(weight[..., None] > 1e-9, total, nearest)
    return mean / np.linalg.norm(mean, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------------------
# The cubic B-spline over the image.


def _bspline_basis(count: int, intervals: int) -> np.ndarray:
    """Uniform cubic B-spline basis at pixel centres 0..count-1, (count, intervals + 3)."""
    x = np.arange(count) * intervals / max(count - 1, 1)
    cell = np.minimum(np.floor(x).astype(int), intervals - 1)
    t = x - cell
    weights = np.stack(
        [(1 - t) ** 3, 3 * t**3 - 6 * t**2 + 4, -3 * t**3 + 3 * t**2 + 3 * t + 1, t**3], -1
    )
    basis = np.zeros((count, intervals + 3))
    for k in range(4):
        basis[np.arange(count), cell + k] = weights[:, k] / 6
    return basis


def _second_difference(n: int) -> np.ndarray:
    d = np.zeros((max(n - 2, 0), n))
    for i in range(n - 2):
        d[i, i : i + 3] = (1, -2, 1)
    return d.T @ d


def fit_spline(
    values: np.ndarray, weight: np.ndarray, knot_px: float, smoothing: float = 1e-3
) -> np.ndarray:
    """Weighted least-squares tensor cubic B-spline of `values` (H, W, C) on a uniform knot
    grid of about `knot_px` pixels, evaluated at every pixel centre: (H, W, C).

    A second-difference penalty (`smoothing` times the mean weight per coefficient) keeps
    the coefficients determined where no pixel has data; it bends the fit very little
    where there are data.
    """
    height, width = weight.shape
    bu = _bspline_basis(width, max(1, round((width - 1) / knot_px)))
    bv = _bspline_basis(height, max(1, round((height - 1) / knot_px)))
    nu, nv = bu.shape[1], bv.shape[1]
    w = weight.astype(float)
    # Normal equations of the Kronecker design without forming it: (nv nu) x (nv nu).
    inner = np.einsum("ij,jc,jd->icd", w, bu, bu)
    gram = np.einsum("ia,ib,icd->acbd", bv, bv, inner).reshape(nv * nu, nv * nu)
    rhs = np.einsum("ia,ij,jc,ijk->ack", bv, w, bu, values).reshape(nv * nu, -1)
    penalty = np.kron(_second_difference(nv), np.eye(nu)) + np.kron(
        np.eye(nv), _second_difference(nu)
    )
    scale = smoothing * max(w.sum(), 1.0) / (nv * nu)
    ridge = 1e-9 * max(w.sum(), 1.0) / (nv * nu) * np.eye(nv * nu)
    coefficients = np.linalg.solve(gram + scale * penalty + ridge, rhs).reshape(nv, nu, -1)
    return np.einsum("ia,abk,jb->ijk", bv, coefficients, bu)


def _spline_field(directions, view, weight, knot_px) -> np.ndarray:
    """The smooth unit field from per-pixel directions: a spline of L - V, plus V."""
    deviation = np.where(weight[..., None] > 0, directions - view, 0)
    field = view + fit_spline(deviation, weight, knot_px)
    return field / np.linalg.norm(field, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------------------


@dataclasses.dataclass
class LightFieldCalibration:
    """The paper's light field and how well it explains the images.

    `directions` (H, W, 3): the smooth field (spline), unit light directions in the camera
    frame at every pixel; `pixel_directions` (H, W, 3): the per-pixel LM solution (NaN
    where not solved); `theta`, `phi` (H, W): eq. (7)'s angles of `directions` (radians,
    see `paper_angles`); `solved` (H, W): pixels of S-bar solved per pixel; `status` (H, W):
    the final solve's `optx.RESULTS` code (-1 where not solved); `boundary` (H, W): S.
    Errors are RMSEs in 8-bit levels.
    """

    model: ShadingModel
    directions: np.ndarray
    pixel_directions: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    solved: np.ndarray
    status: np.ndarray
    boundary: np.ndarray
    view: np.ndarray
    calibration_rmse: float
    heldout_rmse: float
    colocated_heldout_rmse: float
    noise_floor: float
    calibration_frames: list[int]
    heldout_frames: list[int]
    settings: dict
    timings: dict

    @property
    def light(self) -> LightField:
        return self.model.light

    def status_counts(self) -> dict:
        codes = self.status[self.solved]
        names = {int(getattr(optx.RESULTS, n)._value): n for n in optx.RESULTS._name_to_item}
        counts = {"converged": 0, "max_steps": 0, "failed": 0}
        for code, count in zip(*np.unique(codes, return_counts=True), strict=True):
            name = names.get(int(code), "unknown")
            if name == "successful":
                key = "converged"
            elif name in ("max_steps_reached", "nonlinear_max_steps_reached"):
                # `optx.least_squares` out of steps: nonlinear_max_steps_reached.
                key = "max_steps"
            else:
                key = "failed"
            counts[key] += int(count)
        return counts

    def to_json(self) -> dict:
        brdf = self.model.brdf
        solved = self.solved
        spline_vs_pixel = _angle_deg(self.directions[solved], self.pixel_directions[solved])
        out = {
            "model": "field",
            "note": "per-pixel light directions (eq. 7-8), camera frame; L = V on S",
            "rho_tilde": np.asarray(brdf.lobes[0].weight).tolist(),
            "F_tilde": np.asarray(brdf.lobes[1].weight).tolist(),
            "sigma": float(brdf.lobes[1].distribution.sigma),
            "rgb_rmse_calibration": self.calibration_rmse,
            "rgb_rmse_heldout": self.heldout_rmse,
            "rgb_rmse_heldout_colocated": self.colocated_heldout_rmse,
            "noise_floor": self.noise_floor,
            "solver_status": self.status_counts(),
            "solved_pixels": int(solved.sum()),
            "boundary_pixels": int(self.boundary.sum()),
            "median_angle_spline_to_pixel_deg": float(np.median(spline_vs_pixel))
            if spline_vs_pixel.size
            else None,
            "calibration_frames": self.calibration_frames,
            "heldout_frames": self.heldout_frames,
            "settings": self.settings,
            "seconds": self.timings,
        }
        change = _angle_deg(self.directions, self.view)
        out["median_angle_from_view_deg"] = float(np.median(change))
        out["max_angle_from_view_deg"] = float(np.max(change))
        return out

    def npz_arrays(self) -> dict:
        return {
            "directions": self.directions.astype(np.float32),
            "theta": self.theta.astype(np.float32),
            "phi": self.phi.astype(np.float32),
            "pixel_directions": self.pixel_directions.astype(np.float32),
            "solved": self.solved,
            "status": self.status.astype(np.int8),
            "boundary": self.boundary,
        }


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cosine = np.clip(np.sum(a * b, axis=-1), -1, 1)
    return np.degrees(np.arccos(cosine))


def fit_field_brdf(model: ShadingModel, capture, frames, *, max_samples, seed, max_steps):
    """The BRDF (rho~, F~, sigma) under `model`'s light on the usable pixels of `frames`."""
    samples = capture_samples(capture, frames, max_samples=max_samples, seed=seed)
    return fit_model(
        roughness_variants(model),
        samples,
        pixel_predict,
        columns=pixel_columns,
        max_steps=max_steps,
        refine=3,
    )


def calibrate_light_field(
    capture: Capture,
    calibration: int | None = None,
    *,
    prior_deg: float = 6.0,
    knot_px: float | None = None,
    rtol: float = 1e-4,
    atol: float = 1e-6,
    max_steps: int = 24,
    engine: str = "optimistix",
    iterations: int = 10,
    brdf_rounds: int = 3,
    brdf: BRDF | None = None,
    falloff: str = "auto",
    masks: MaskOptions | None = None,
    max_samples: int = 12_000,
    heldout_samples: int = 40_000,
    seed: int = 0,
    progress=None,
) -> LightFieldCalibration:
    """The paper's per-pixel light field from the calibration frames (default: the first
    60%), judged on the held-out frames.

    1. BRDF: the paper's model with L = V fitted on the calibration frames' usable pixels
       (or `brdf` as given). `falloff` "auto" also fits it with an inverse-square falloff
       from the lens and keeps that only if it is 1% better on the held-out frames: the
       paper's field has unit irradiance, so an unmodelled falloff would become direction
       errors (measured: ~30 degrees). "none" / "inverse_square" force the choice.
    2. Per pixel of S-bar (usable, not specular, in at least one calibration frame), L by LM
       on eq. (8) over all calibration frames, propagated from L = V on S outwards in
       bands, with a prior towards the solved neighbours (`prior_deg`, see the module).
       `engine` "optimistix" (the reference): `optx.LevenbergMarquardt(rtol, atol)` with
       at most `max_steps` steps; "closed-form": `solve_pixels_closed_form`, exactly
       `iterations` iterations of a batched LM written out for the 2 unknowns, several
       times faster and as accurate on synthetic captures (`benchmarks/light_lm.py`).
    3. A cubic B-spline (knots every `knot_px`, default ~1/8 of the image) of the solution,
       then every pixel solved again with the prior towards the spline, and the spline
       refitted: the field.
    4. With `brdf_rounds` > 1, the BRDF is refitted under the field and steps 2-3 repeated
       from the field.

    Raises `CtjaxError` for an unknown `engine`, without depth and normals, without
    specular pixels (the boundary S is empty) or without pixels in S-bar.
    """
    if engine not in _ENGINES:
        raise CtjaxError(f"unknown light-field engine {engine!r}; known: {', '.join(_ENGINES)}")
    if engine == "closed-form" and not (
        isinstance(iterations, int | np.integer)
        and not isinstance(iterations, bool)
        and iterations >= 1
    ):
        raise CtjaxError(f"iterations must be a positive integer, got {iterations!r}")
    say = progress or (lambda message: None)
    started = time.perf_counter()
    timings = {}
    if any(f.depth is None or f.normals is None for f in capture.frames):
        raise CtjaxError(f"{capture.root}: the light field needs depth and normals for every frame")
    calib, heldout = split_frames(len(capture), calibration, source=capture.root)
    sets = capture_sets(capture, masks or MaskOptions())
    boundary = np.any([sets[i].specular for i in calib], axis=0)
    if not boundary.any():
        raise CtjaxError(
            f"{capture.root}: no specular pixels (S is empty) in the calibration frames "
            f"{calib}: the light field's boundary condition L = V on S needs a highlight"
        )
    dtype = jax.dtypes.canonicalize_dtype(np.float64)
    observed = np.zeros(boundary.shape, bool)
    for i in calib:
        observed |= usable_mask(capture.frames[i]) & ~sets[i].specular & ~sets[i].saturated
    todo = observed & ~boundary
    if not todo.any():
        raise CtjaxError(f"{capture.root}: no pixel of S-bar in the calibration frames {calib}")
    height, width = boundary.shape
    if knot_px is None:
        knot_px = max(8.0, max(height, width) / 8)
    prior_scale = 1 / math.radians(prior_deg)
    if engine == "optimistix":
        solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

        def solve(problems, brdf):
            return solve_pixels(problems, brdf, prior_scale, solver, max_steps)
    else:

        def solve(problems, brdf):
            return solve_pixels_closed_form(
                problems, brdf, prior_scale, int(iterations), rtol, atol
            )

    rows, cols = np.mgrid[0:height, 0:width]
    view = view_directions(capture.camera, rows.astype(float), cols.astype(float))
    settings = {
        "prior_deg": prior_deg,
        "knot_px": knot_px,
        "rtol": rtol,
        "atol": atol,
        "engine": engine,
        "brdf_rounds": brdf_rounds,
    }
    if engine == "optimistix":
        settings["max_steps"] = max_steps
    else:
        settings["iterations"] = iterations

    tick = time.perf_counter()
    depth = np.concatenate([capture.frames[i].depth[usable_mask(capture.frames[i])] for i in calib])
    reference = float(np.median(depth))
    choices = {"none": (), "inverse_square": (InverseSquare(reference),)}
    if falloff not in (*choices, "auto"):
        raise CtjaxError(f"unknown falloff {falloff!r}; known: auto, {', '.join(choices)}")
    if brdf is None:
        # The paper's model (L = V), with and without the inverse-square falloff, which a
        # unit-irradiance field would otherwise turn into direction errors; as for the
        # near light, the simpler one wins unless the other is 1% better on held-out frames.
        say(f"BRDF: the paper's model (L = V) on frames {calib}")
        test = capture_samples(capture, heldout, max_samples=max_samples, seed=seed + 1)
        fits = {}
        for name in choices if falloff == "auto" else (falloff,):
            light = ColocatedLight(falloff=choices[name])
            model = strongly_typed(ShadingModel(paper_model().brdf, light))
            fits[name] = fit_field_brdf(
                model, capture, calib, max_samples=max_samples, seed=seed, max_steps=100
            )
        heldout_fit = {n: float(rmse_levels(f.model, test, pixel_predict)) for n, f in fits.items()}
        lowest = min(heldout_fit.values())
        falloff = next(n for n in fits if heldout_fit[n] <= 1.01 * lowest)
        fit = fits[falloff]
        fixed_brdf = False
    else:
        falloff = "none" if falloff == "auto" else falloff
        light = ColocatedLight(falloff=choices[falloff])
        fit = FitResult(ShadingModel(brdf, light), jnp.inf, jnp.inf, "given", 0, ())
        fixed_brdf = True
    settings["falloff"] = falloff
    obs = _observations(capture, calib, sets, choices[falloff], dtype)
    timings["brdf"] = time.perf_counter() - tick

    distance = ndimage.distance_transform_edt(~boundary)
    field = view
    solution = None
    for round_ in range(brdf_rounds):
        brdf = fit.model.brdf
        tick = time.perf_counter()
        if round_ == 0:
            # Propagation from S: bands of doubling width, each from its solved neighbours.
            directions = np.where(boundary[..., None], view, np.nan)
            solved = boundary.copy()
            edges = [0.0, _FIRST_BAND_PX]
            while edges[-1] < distance[todo].max():
                edges.append(2 * edges[-1])
            for lo, hi in itertools.pairwise(edges):
                band = todo & (distance > lo) & (distance <= hi)
                if not band.any():
                    continue
                start = _neighbour_mean(np.nan_to_num(directions), solved).reshape(-1, 3)
                index = np.flatnonzero(band)
                out = _solve(obs, index, start, start, brdf, solve)
                directions.reshape(-1, 3)[index] = out["direction"]
                solved |= band
            say(f"propagated from S over {len(edges) - 1} bands")
        else:
            directions = field.copy()
        spline = _spline_field(np.nan_to_num(directions), view, todo.astype(float), knot_px)
        # Every pixel once more, with the prior towards the spline (smoothness), then the
        # spline of that solution is the field.
        index = np.flatnonzero(todo)
        start = np.where(np.isfinite(directions), directions, spline).reshape(-1, 3)
        start = np.where(np.isfinite(start), start, view.reshape(-1, 3))
        solution = _solve(obs, index, start, spline.reshape(-1, 3), brdf, solve)
        pixel_directions = np.full((height, width, 3), np.nan)
        pixel_directions.reshape(-1, 3)[index] = solution["direction"]
        field = _spline_field(np.nan_to_num(pixel_directions), view, todo.astype(float), knot_px)
        timings[f"field_round_{round_}"] = time.perf_counter() - tick
        if round_ + 1 < brdf_rounds and not fixed_brdf:
            say("BRDF: refitted under the light field")
            tick = time.perf_counter()
            model = ShadingModel(brdf, LightField(field, falloff=choices[falloff]))
            fit = fit_field_brdf(
                model, capture, calib, max_samples=max_samples, seed=seed, max_steps=50
            )
            timings[f"brdf_round_{round_ + 1}"] = time.perf_counter() - tick

    status = np.full((height, width), -1, np.int64)
    status.reshape(-1)[index] = solution["result"]
    final = ShadingModel(fit.model.brdf, LightField(field, falloff=choices[falloff]))
    tick = time.perf_counter()
    train = capture_samples(capture, calib, max_samples=heldout_samples, seed=seed)
    test = capture_samples(capture, heldout, max_samples=heldout_samples, seed=seed + 1)
    calibration_rmse = float(rmse_levels(final, train, pixel_predict))
    heldout_rmse = float(rmse_levels(final, test, pixel_predict))
    colocated = ShadingModel(fit.model.brdf, ColocatedLight(falloff=choices[falloff]))
    colocated_rmse = float(rmse_levels(colocated, test, pixel_predict))
    noise = noise_floor_levels(capture, heldout, final)
    timings["evaluation"] = time.perf_counter() - tick
    timings["total"] = time.perf_counter() - started
    if not np.isfinite(heldout_rmse):
        raise CtjaxError("the light field did not produce finite estimates")
    theta, phi = paper_angles(field)
    return LightFieldCalibration(
        final,
        field,
        pixel_directions,
        theta,
        phi,
        todo,
        status,
        boundary,
        view,
        calibration_rmse,
        heldout_rmse,
        colocated_rmse,
        noise,
        calib,
        heldout,
        settings,
        {k: round(v, 2) for k, v in timings.items()},
    )
