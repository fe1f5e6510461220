"""The general fitter's Levenberg-Marquardt: optimistix's (on its own linearisation, QR or
normal equations) against `ctjax.solvers.DenseLM` (the Jacobian matrix, the default).

    python benchmarks/fit_step.py [--pixels 2048 8192 32768 --steps 20 --repeats 5]

The near-light model of `calibrate_near_light` (a point light 6 mm off the lens, Lambertian
+ Beckmann, 10 free parameters) fitted to the pixels of a synthetic capture. Per solver:
milliseconds per step (a warm `--steps`-step solve with zero tolerances divided by the
steps, median of `--repeats`, spread min-max; DenseLM recomputes the Jacobian only after
an accepted step, so once converged its steps are cheap: compare whole fits); a whole fit
with the fitters' tolerances (1e-6): its warm time, steps and RMSE (8-bit levels); and the
model and its Jacobian alone for scale. Prints a table and one JSON line per configuration.
"""

import argparse
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import lineax as lx  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
from _results import emit  # noqa: E402

from ctjax import Status  # noqa: E402
from ctjax._buckets import padded  # noqa: E402
from ctjax.calibration._near_light import near_light_starts  # noqa: E402
from ctjax.fitting import pixel_columns, pixel_predict  # noqa: E402
from ctjax.fitting._fit import _masked_residuals, initial_weights  # noqa: E402
from ctjax.fitting._parameters import constrained, free_parameters, unconstrained  # noqa: E402
from ctjax.heldout import HeldOut  # noqa: E402
from ctjax.io import load_capture  # noqa: E402
from ctjax.solvers import DenseLM, least_squares  # noqa: E402
from ctjax.synth import SynthOptions, synthesize  # noqa: E402


def problem(pixels: int):
    """The residual function (8-bit levels) and its start, on `pixels` pixels."""
    side = int(np.ceil(np.sqrt(pixels / 5 / 0.6)))  # 5 frames, about 60% usable
    options = SynthOptions(
        width=side, height=side, frames=5, texture=False, seed=5,
        effects={"light_offset": (6.0, -2.0, 0.0)},
    )  # fmt: skip
    capture = load_capture(synthesize(Path(tempfile.mkdtemp()) / "c", options))
    train = HeldOut.split(capture, None, max_samples=pixels, heldout_samples=1000).train
    samples, mask = padded(train, len(train.values))
    model = initial_weights(near_light_starts((), capture)[0], samples, pixel_columns, mask)
    parameters = free_parameters(model)

    def residuals(u, _):
        fitted = constrained(model, parameters, u)
        return 255 * _masked_residuals(fitted, samples, mask, pixel_predict).reshape(-1)

    return residuals, unconstrained(model, parameters), len(samples.values), len(parameters)


def timed(fn, y, repeats):
    jax.block_until_ready(fn(y))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(y))
        times.append(time.perf_counter() - start)
    return np.asarray(times)


def solvers(tolerance: float) -> dict:
    """The solvers compared, all with `tolerance` as rtol and atol."""
    t = tolerance
    return {
        "optimistix-qr": optx.LevenbergMarquardt(rtol=t, atol=t, linear_solver=lx.QR()),
        "optimistix-normal-cholesky": optx.LevenbergMarquardt(
            rtol=t, atol=t, linear_solver=lx.Normal(lx.Cholesky())
        ),
        "DenseLM": DenseLM(rtol=t, atol=t),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", type=int, nargs="+", default=[2048, 8192, 32768])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(
        f"{'pixels':>7} {'solver':>26} {'ms/step':>8} {'spread':>13} "
        f"{'fit ms':>8} {'steps':>5} {'RMSE':>8}"
    )
    for pixels in args.pixels:
        residuals, start, rows, _ = problem(pixels)
        flat = lambda u, residuals=residuals: residuals(u, None)  # noqa: E731
        model_ms = 1e3 * np.median(timed(jax.jit(flat), start, args.repeats))
        jac_ms = 1e3 * np.median(timed(jax.jit(jax.jacfwd(flat)), start, args.repeats))
        fixed, converging = solvers(0.0), solvers(1e-6)  # the fitters' tolerances
        for name in fixed:
            steps = eqx.filter_jit(
                lambda y, s=fixed[name], f=flat: least_squares(f, s, y, args.steps)[0]
            )
            per_step = 1e3 * timed(steps, start, args.repeats) / args.steps
            fit = eqx.filter_jit(lambda y, s=converging[name], f=flat: least_squares(f, s, y, 200))
            fit_ms = 1e3 * float(np.median(timed(fit, start, args.repeats)))
            solution, status, taken = fit(start)
            rmse = float(np.sqrt(np.mean(np.square(flat(solution)))))
            median = float(np.median(per_step))
            print(
                f"{rows:>7} {name:>26} {median:8.2f} {per_step.min():6.2f}-"
                f"{per_step.max():<6.2f} {fit_ms:8.1f} {int(taken):>5} {rmse:8.4f}"
            )
            emit(
                {
                    "pixels": rows,
                    "solver": name,
                    "ms_per_step_median": median,
                    "ms_per_step_min": float(per_step.min()),
                    "ms_per_step_max": float(per_step.max()),
                    "fit_ms_median": fit_ms,
                    "fit_steps": int(taken),
                    "fit_status": Status(int(status)).name,
                    "fit_rmse_levels": rmse,
                    "model_ms": float(model_ms),
                    "jacfwd_ms": float(jac_ms),
                    "dtype": str(jnp.asarray(0.0).dtype),
                }
            )


if __name__ == "__main__":
    main()
