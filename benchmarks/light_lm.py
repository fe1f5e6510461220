"""Per-pixel light directions (eq. 8) by Levenberg-Marquardt: throughput and accuracy.

    python benchmarks/light_lm.py [--width 640 --height 480 --frames 3 --scipy-pixels 500]

One 640x480 frame of per-pixel problems as `ctjax.calibration.calibrate_light_field` solves
them: the paper's model (Lambertian + Beckmann, rho~ = (2.4, 1.1, 0.85), F~ = 0.3,
sigma = 0.2), the light at (6, 0, 0) mm from the lens, surface points 60-80 mm away, each
pixel seen in `--frames` frames with different normals (the light is rigid with the camera,
so L is shared), data noise-free and with 1 level of noise; the start is the truth turned by
4 degrees in a random direction (the propagation's neighbour mean), no prior. In one run:

- optx-lm: ctjax's `solve_pixels`, `optx.LevenbergMarquardt` vmapped over the pixels, for
  several (rtol, atol, max_steps); under vmap every pixel runs until the slowest stops.
- scipy-lm: `scipy.optimize.least_squares(method="lm")` per pixel on a sample, with the
  residuals and the Jacobian jitted in JAX (what a careful user writes).
- closed-form-lm: ctjax's `solve_pixels` with `ClosedFormLM` (`--engine closed-form`), a batched LM
  written out in JAX, a fixed number of iterations, the Jacobian by `jax.jacfwd`, the 2x2
  damped normal equations solved by the explicit formula.

Compile time is reported separately (first call minus a warm call); pixels per second and
frame time are for warm calls (best of `--repeats`). Accuracy: median and 90th percentile
of the angle to the truth. Prints a table and one JSON line per configuration.
"""

import argparse
import math
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
from _results import emit  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from ctjax._vector import Vec3, tangent_direction  # noqa: E402
from ctjax.calibration import (  # noqa: E402
    ClosedFormLM,
    PixelProblem,
    pixel_residuals,
    solve_pixels,
)
from ctjax.lobes import cook_torrance_brdf  # noqa: E402

BRDF = cook_torrance_brdf((2.4, 1.1, 0.85), 0.3, 0.2)
LIGHT_MM = np.array([6.0, 0.0, 0.0])
START_ERROR_DEG = 4.0
# (rtol, atol, max_steps). optimistix's defaults-like (1e-6, 1e-8, 100) took 14 s for a
# 160x120 frame: under vmap the slowest pixel sets the time; see the docstring.
OPTX_CONFIGS = ((1e-4, 1e-6, 24), (1e-3, 1e-5, 12), (1e-3, 1e-5, 8), (1e-2, 1e-4, 6))


def problems(width, height, frames, noise, seed=0, dtype=np.float64):
    """Per-pixel problems of one frame, and the true light directions (P, 3)."""
    rng = np.random.default_rng(seed)
    focal = 0.9 * width
    v, u = np.mgrid[0:height, 0:width]
    ray = np.stack(
        [(u - (width - 1) / 2) / focal, (v - (height - 1) / 2) / focal, np.ones(u.shape)]
    )
    ray = ray.reshape(3, -1).T
    view = -ray / np.linalg.norm(ray, axis=-1, keepdims=True)
    point = ray * rng.uniform(60, 80, (len(ray), 1))
    truth = LIGHT_MM - point
    truth /= np.linalg.norm(truth, axis=-1, keepdims=True)
    # Normals 5-40 degrees from the view, a different one in each frame.
    tilt = np.radians(rng.uniform(5, 40, (len(ray), frames)))
    azimuth = rng.uniform(0, 2 * np.pi, (len(ray), frames))
    e1 = np.cross(view, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(view, e1)
    normal = (
        np.cos(tilt)[..., None] * view[:, None]
        + (np.sin(tilt) * np.cos(azimuth))[..., None] * e1[:, None]
        + (np.sin(tilt) * np.sin(azimuth))[..., None] * e2[:, None]
    )
    # The start: the truth turned by START_ERROR_DEG in a random direction.
    side = np.cross(truth, rng.normal(size=truth.shape))
    side /= np.linalg.norm(side, axis=-1, keepdims=True)
    angle = math.radians(START_ERROR_DEG)
    start = math.cos(angle) * truth + math.sin(angle) * side
    vec = lambda a: Vec3.from_array(jnp.asarray(a, dtype))  # noqa: E731
    clean = jax.vmap(
        jax.vmap(lambda n, light, view: BRDF.radiance(n, light, view), (0, None, None))
    )(vec(normal), vec(truth), vec(view))
    values = np.asarray(clean) + rng.normal(0, noise / 255, np.shape(clean))
    problem = PixelProblem(
        vec(view),
        vec(normal),
        jnp.asarray(values, dtype),
        jnp.ones((len(ray), frames), dtype),
        jnp.ones((len(ray), frames), dtype),
        jnp.zeros((len(ray), frames, 3), dtype),  # one albedo: the BRDF's own
        vec(start),
        vec(start),
    )
    return problem, truth


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(np.asarray(a) * b, axis=-1), -1, 1)))


def timed(fn, repeats):
    start = time.perf_counter()
    jax.block_until_ready(fn())
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    best = min(times)
    return out, best, max(first - best, 0.0)


def scipy_loop(problem, count, seed=0):
    """scipy least_squares per pixel on `count` random pixels; returns (indices, directions)."""
    index = np.random.default_rng(seed).choice(problem.values.shape[0], count, replace=False)
    pick = jax.tree_util.tree_map(lambda a: a[index], problem)

    @jax.jit
    def residual(y, one):
        return pixel_residuals(y, one, BRDF, 0.0)

    jacobian = jax.jit(jax.jacfwd(residual))
    out = []
    for k in range(count):
        one = jax.tree_util.tree_map(lambda a, k=k: a[k], pick)
        fit = least_squares(
            lambda y, one=one: np.asarray(residual(jnp.asarray(y), one)),
            np.zeros(2),
            jac=lambda y, one=one: np.asarray(jacobian(jnp.asarray(y), one)),
            method="lm",
        )
        out.append(np.asarray(tangent_direction(one.start, jnp.asarray(fit.x)).to_array()))
    return index, np.array(out)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--scipy-pixels", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    pixels = args.width * args.height
    rows = []
    for noise in (0.0, 1.0):
        problem, truth = problems(args.width, args.height, args.frames, noise)
        start = np.asarray(jnp.stack([problem.start.x, problem.start.y, problem.start.z], axis=-1))
        rows.append(("start", noise, None, None, angle_deg(start, truth)))
        for rtol, atol, steps in OPTX_CONFIGS:
            solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
            out, seconds, compile_s = timed(
                lambda solver=solver, steps=steps, problem=problem: solve_pixels(
                    problem, BRDF, 0.0, solver, steps
                ),
                args.repeats,
            )
            name = f"optx-lm rtol={rtol:g} atol={atol:g} max_steps={steps}"
            steps_taken = np.asarray(out.steps)
            rows.append(
                (
                    name,
                    noise,
                    seconds,
                    compile_s,
                    angle_deg(out.direction, truth),
                    f"steps median {np.median(steps_taken):.0f} max {steps_taken.max()}, "
                    f"converged {100 * np.mean(np.asarray(out.result) == 0):.0f}%",
                )
            )
        for iterations in (5, 8, 10, 12):  # 10: calibrate_light_field's default
            out, seconds, compile_s = timed(
                lambda iterations=iterations, problem=problem: solve_pixels(
                    problem, BRDF, 0.0, ClosedFormLM(iterations)
                ),
                args.repeats,
            )
            converged = np.mean(np.asarray(out.result) == 0)
            rows.append(
                (
                    f"closed-form-lm iterations={iterations}",
                    noise,
                    seconds,
                    compile_s,
                    angle_deg(out.direction, truth),
                    f"converged {100 * converged:.0f}%",
                )
            )
        tick = time.perf_counter()
        index, out = scipy_loop(problem, min(10, args.scipy_pixels))
        compile_s = time.perf_counter() - tick
        tick = time.perf_counter()
        index, out = scipy_loop(problem, args.scipy_pixels, seed=1)
        seconds = (time.perf_counter() - tick) * pixels / args.scipy_pixels
        rows.append(
            (
                f"scipy-lm loop ({args.scipy_pixels} px, extrapolated)",
                noise,
                seconds,
                compile_s,
                angle_deg(out, truth[index]),
            )
        )
    print(
        f"{pixels} pixels ({args.width}x{args.height}), {args.frames} frames per pixel, "
        f"start {START_ERROR_DEG} deg off, {jax.devices()[0].device_kind}, float64"
    )
    print(
        f"{'engine':<48} {'noise':>5} {'frame s':>8} {'px/s':>10} {'compile s':>9} "
        f"{'median deg':>10} {'p90 deg':>8}"
    )
    for name, noise, seconds, compile_s, errors, *extra in rows:
        frame = f"{seconds:8.2f}" if seconds is not None else " " * 8
        rate = f"{pixels / seconds:10.0f}" if seconds is not None else " " * 10
        comp = f"{compile_s:9.1f}" if compile_s is not None else " " * 9
        print(
            f"{name:<48} {noise:5.1f} {frame} {rate} {comp} {np.median(errors):10.3f} "
            f"{np.percentile(errors, 90):8.3f} {' '.join(extra)}"
        )
    for name, noise, seconds, compile_s, errors, *_ in rows:
        emit(
            {
                "engine": name,
                "noise_levels": noise,
                "pixels": pixels,
                "frame_seconds": seconds,
                "pixels_per_second": pixels / seconds if seconds else None,
                "compile_seconds": compile_s,
                "median_angle_deg": float(np.median(errors)),
                "p90_angle_deg": float(np.percentile(errors, 90)),
            }
        )


if __name__ == "__main__":
    main()
