"""`ctjax batch` against running the captures one after the other, same run.

    python benchmarks/batch.py [--captures 4] [--size 160x128] [--frames 5]
                               [--steps fit,calibrate-light] [--workers 2] [--repeats 2]

On `--captures` small synthetic captures (seeds 0, 1, ...), times, warm (a first untimed
pass of each fills the compilation cache and the kept programs, in a folder of its own):

- `sequential_commands`: one `ctjax STEP CAPTURE` process per capture and step, one after
  the other (what a user without `batch` runs);
- `batch_workers0`: `ctjax batch --workers 0` (one process, the captures one after the other);
- `batch_workersN`: `ctjax batch --workers N` (a local Dask cluster).

Prints the medians over `--repeats` and the ratios of the Dask batch to both, and one JSON
line (also appended to `benchmarks/results/`).
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _results import emit

CTJAX = [sys.executable, "-m", "ctjax.cli"]


def _run(argv, env) -> float:
    started = time.perf_counter()
    subprocess.run(argv, env=env, check=True, capture_output=True)
    return time.perf_counter() - started


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", type=int, default=4)
    parser.add_argument("--size", default="160x128")
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--steps", default="fit,calibrate-light")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    width, height = args.size.split("x")
    steps = args.steps.split(",")
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        env = {**os.environ, "CTJAX_CACHE_DIR": str(root / "cache")}
        captures = []
        for seed in range(args.captures):
            capture = root / f"capture{seed}"
            options = ["--width", width, "--height", height, "--frames", str(args.frames)]
            subprocess.run(
                [*CTJAX, "synth", str(capture), *options, "--seed", str(seed)],
                check=True,
                capture_output=True,
                env=env,
            )
            captures.append(str(capture))

        def sequential(out):
            for capture in captures:
                for step in steps:
                    json_path = Path(out) / f"{Path(capture).name}-{step}.json"
                    json_path.parent.mkdir(parents=True, exist_ok=True)
                    subprocess.run(
                        [*CTJAX, step, capture, "--json", str(json_path)],
                        env=env,
                        check=True,
                        capture_output=True,
                    )

        def batch(out, workers):
            return [*CTJAX, "batch", *captures, "--out", str(out), "--steps", args.steps]

        times = {
            "sequential_commands": [],
            "batch_workers0": [],
            f"batch_workers{args.workers}": [],
        }
        for repeat in range(args.repeats + 1):  # the first pass only warms the caches
            started = time.perf_counter()
            sequential(root / f"seq{repeat}")
            seconds = {"sequential_commands": time.perf_counter() - started}
            seconds["batch_workers0"] = _run(
                [*batch(root / f"b0-{repeat}", 0), "--workers", "0"], env
            )
            seconds[f"batch_workers{args.workers}"] = _run(
                [*batch(root / f"bn-{repeat}", args.workers), "--workers", str(args.workers)],
                env,
            )
            if repeat:
                for name, value in seconds.items():
                    times[name].append(value)
    medians = {name: statistics.median(values) for name, values in times.items()}
    dask = medians[f"batch_workers{args.workers}"]
    row = {
        "captures": args.captures,
        "size": args.size,
        "frames": args.frames,
        "steps": args.steps,
        "workers": args.workers,
        "cpus": os.cpu_count(),
        **{f"{name}_s": round(value, 2) for name, value in medians.items()},
        "ratio_vs_sequential_commands": round(dask / medians["sequential_commands"], 3),
        "ratio_vs_batch_workers0": round(dask / medians["batch_workers0"], 3),
    }
    print(
        f"{args.captures} captures {args.size} x{args.frames}, steps {args.steps}: "
        f"one command after another {medians['sequential_commands']:.1f} s, batch --workers 0 "
        f"{medians['batch_workers0']:.1f} s, batch --workers {args.workers} {dask:.1f} s "
        f"(ratios {row['ratio_vs_sequential_commands']} and {row['ratio_vs_batch_workers0']})"
    )
    emit(row)


if __name__ == "__main__":
    main()
