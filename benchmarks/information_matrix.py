"""The standard errors' information matrix `J^T J`: the Jacobian's product as one matrix
(`jac.T @ jac`) against its columns taken apart (`ctjax.solvers._gram.gram`).

    python benchmarks/information_matrix.py [--frames 12 --width 192 --height 160 --repeats 3]

Synthesises a capture with auto-exposure (`ctjax synth --exposure 0.15 --light-offset 3 0
0`), runs `ctjax calibrate-light --falloff none --effects frame_exposure` on it and keeps
the arguments of the last standard errors it computes (the chosen near light on every
frame's tracks: sigma, the lens-plane offset and one exposure per frame after the first),
and of the same with the exposures held (3 parameters). For each: the warm time of the
forward-mode Jacobian (`jax.jacfwd`) of the projected residuals times itself, both ways
(median of `--repeats`, compiled once before), and the largest difference between the two
matrices relative to their largest entry. One JSON line per model.
"""

import argparse
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _results import emit  # noqa: E402

from ctjax.cli import main as ctjax_main  # noqa: E402
from ctjax.fitting import _map_least_squares as map_fit  # noqa: E402
from ctjax.fitting._parameters import as_vector, free_parameters  # noqa: E402
from ctjax.solvers._gram import gram  # noqa: E402


def _kept_arguments(args) -> tuple:
    """The arguments of the last `_covariance` call of `ctjax calibrate-light` on a
    synthesised capture."""
    kept = []
    covariance = map_fit._covariance

    def keeping(*arguments):
        kept.append(arguments)
        return covariance(*arguments)

    map_fit._covariance = keeping
    try:
        with tempfile.TemporaryDirectory() as folder:
            root = Path(folder) / "capture"
            size = ["--width", str(args.width), "--height", str(args.height)]
            synth = ["synth", str(root), "--frames", str(args.frames), *size, "--seed", "3"]
            assert ctjax_main([*synth, "--exposure", "0.15", "--light-offset", "3", "0", "0"]) == 0
            out = str(Path(folder) / "light.json")
            light = ["calibrate-light", str(root), "--falloff", "none", "--json", out]
            assert ctjax_main([*light, "--effects", "frame_exposure"]) == 0
    finally:
        map_fit._covariance = covariance
    return kept[-1]


def _timed(function, repeats, *arguments):
    jax.block_until_ready(function(*arguments))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(function(*arguments))
        times.append(time.perf_counter() - start)
    return float(np.median(times)), np.asarray(out)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--width", type=int, default=192)
    parser.add_argument("--height", type=int, default=160)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    model, samples, names, per_point = _kept_arguments(args)
    for held in ((), ("effects[0].log_exposure",)):
        frozen = set(names) | set(held)
        parameters = free_parameters(
            model, lambda n, frozen=frozen: n in frozen or map_fit._weights_frozen(n)
        )
        flat, rebuilt = as_vector(model, parameters)

        def jacobian(theta, samples, rebuilt=rebuilt):
            residual = lambda t: map_fit._projected(rebuilt(t), samples, per_point)[2]  # noqa: E731
            return jax.jacfwd(lambda t: residual(t).reshape(-1))(theta)

        whole = jax.jit(lambda t, s, jacobian=jacobian: jacobian(t, s).T @ jacobian(t, s))
        apart = jax.jit(lambda t, s, jacobian=jacobian: gram(jacobian(t, s)))
        whole_s, a = _timed(whole, args.repeats, flat, samples)
        apart_s, b = _timed(apart, args.repeats, flat, samples)
        row = {
            "parameters": int(flat.size),
            "residuals": int(np.prod(samples.values.shape)),
            "whole_s": whole_s,
            "columns_apart_s": apart_s,
            "speedup": whole_s / apart_s,
            "max_relative_difference": float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(a))),
        }
        print(
            f"{row['parameters']} parameters, {row['residuals']} residuals: J^T J "
            f"{whole_s:.3f} s as one matrix, {apart_s:.3f} s from the columns "
            f"({row['speedup']:.1f}x; the same within {row['max_relative_difference']:.1e})"
        )
        emit(row)


if __name__ == "__main__":
    main()
