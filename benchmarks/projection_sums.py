"""The variable projection's sums over views in the LM fitters: as adds of slices
(`over_views`, the branch and bound's) against one reduction (`over_views_at_once`).

    python benchmarks/projection_sums.py [--frames 12 --width 192 --height 160 --repeats 3]

Takes the arguments of the last standard errors of `ctjax calibrate-light --falloff none
--effects frame_exposure` on a synthesised capture with auto-exposure (as
`benchmarks/information_matrix.py`: sigma, the lens-plane offset and one exposure per frame
after the first), and the same model without its image effects (3 parameters). For each
and both ways of summing: the warm time of the projected residuals and of their
forward-mode Jacobian (`jax.jacfwd`, as DenseLM takes it), compiled as the fitters are
(`ctjax._programs.compiler_options`), the median of `--repeats`; and the largest difference
between the two Jacobians relative to their largest entry. One JSON line per model. Then
DenseLM on the model with gains from a moved start: its Jacobian in one forward pass
against the shading's and the image effects' columns in a pass each (`JacobianBlocks`).
"""

import argparse

import equinox as eqx
import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _results import emit  # noqa: E402
from information_matrix import _kept_arguments, _timed  # noqa: E402

from ctjax._programs import compiler_options  # noqa: E402
from ctjax.estimation._variable_projection import over_views, over_views_at_once  # noqa: E402
from ctjax.fitting import _map_least_squares as map_fit  # noqa: E402
from ctjax.fitting._parameters import (  # noqa: E402
    as_vector,
    constrained,
    free_parameters,
    unconstrained,
)
from ctjax.solvers import DenseLM, JacobianBlocks, least_squares  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--width", type=int, default=192)
    parser.add_argument("--height", type=int, default=160)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    model, samples, names, per_point = _kept_arguments(args)
    options = compiler_options()
    for label, fitted in (
        ("gains", model),
        ("no_effects", eqx.tree_at(lambda m: m.effects, model, ())),
    ):
        parameters = free_parameters(
            fitted, lambda n: n in set(names) or map_fit._weights_frozen(n)
        )
        flat, rebuilt = as_vector(fitted, parameters)
        row = {"model": label, "parameters": int(flat.size)}
        jacobians = {}
        for way, over in (("adds", over_views), ("at_once", over_views_at_once)):

            def residual(theta, samples, rebuilt=rebuilt, over=over):
                return map_fit._projected(rebuilt(theta), samples, per_point, over)[2].reshape(-1)

            def jacobian(theta, samples, residual=residual):
                return jax.jacfwd(lambda t: residual(t, samples))(theta)

            row[f"residuals_{way}_s"] = _timed(
                jax.jit(residual, compiler_options=options), args.repeats, flat, samples
            )[0]
            row[f"jacobian_{way}_s"], jacobians[way] = _timed(
                jax.jit(jacobian, compiler_options=options), args.repeats, flat, samples
            )
        a, b = jacobians["adds"], jacobians["at_once"]
        row["residuals"] = int(np.prod(samples.values.shape))
        row["jacobian_speedup"] = row["jacobian_adds_s"] / row["jacobian_at_once_s"]
        row["max_relative_difference"] = float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(a)))
        print(
            f"{label}: {row['parameters']} parameters, {row['residuals']} residuals: the "
            f"Jacobian {row['jacobian_adds_s']:.3f} s with adds, {row['jacobian_at_once_s']:.3f} s "
            f"at once ({row['jacobian_speedup']:.1f}x); the residuals "
            f"{row['residuals_adds_s']:.3f} / {row['residuals_at_once_s']:.3f} s; the same "
            f"within {row['max_relative_difference']:.1e}"
        )
        emit(row)
    emit(_blocks(model, samples, names, per_point, options, args.repeats))


def _blocks(model, samples, names, per_point, options, repeats) -> dict:
    """DenseLM from the fit's start with every exposure moved by 0.03: the Jacobian in one
    forward pass, against the shading's and the effects' columns in a pass each
    (`JacobianBlocks`, as `_map_least_squares` passes them)."""
    moved = eqx.tree_at(
        lambda m: m.effects[0].log_exposure, model, model.effects[0].log_exposure + 0.03
    )
    parameters = free_parameters(moved, lambda n: n in set(names) or map_fit._weights_frozen(n))
    start = unconstrained(moved, parameters)
    effects = [p.name.startswith("effects") for p in parameters]
    blocks = JacobianBlocks(
        (
            tuple(s for s, e in zip(start, effects, strict=True) if not e),
            tuple(s for s, e in zip(start, effects, strict=True) if e),
        )
    )

    def listed(y):
        if not isinstance(y, JacobianBlocks):
            return y
        shading, image = iter(y[0]), iter(y[1])
        return [next(image) if e else next(shading) for e in effects]

    def solve(y0, samples):
        def residuals(y):
            fitted = constrained(moved, parameters, listed(y))
            return 255 * map_fit._projected(fitted, samples, per_point)[2].reshape(-1)

        return least_squares(residuals, DenseLM(), y0, 100)

    row = {"model": "gains_lm"}
    for way, y0 in (("one_pass", start), ("blocks", blocks)):
        program = jax.jit(lambda y, s, solve=solve: solve(y, s)[2], compiler_options=options)
        row[f"lm_{way}_s"], _ = _timed(program, repeats, y0, samples)
        row[f"lm_{way}_steps"] = int(program(y0, samples))
    row["lm_speedup"] = row["lm_one_pass_s"] / row["lm_blocks_s"]
    print(
        f"DenseLM, 14 parameters from moved exposures: {row['lm_one_pass_s']:.2f} s with the "
        f"Jacobian in one pass, {row['lm_blocks_s']:.2f} s in the shading's and the effects' "
        f"blocks ({row['lm_speedup']:.2f}x; {row['lm_one_pass_steps']} and "
        f"{row['lm_blocks_steps']} steps)"
    )
    return row


if __name__ == "__main__":
    main()
