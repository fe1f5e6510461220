"""Start-up: a repeated `ctjax fit` against `python -c "import ctjax, jax"`, in one run.

The yardstick of issue #43 ("a repeated command pays for its work, not for tracing: at
most 1.5x the import time"): a synthetic 320x256 x 5 capture, `ctjax fit` run once to keep
its programs (in a scratch `CTJAX_CACHE_DIR`), then `--pairs` interleaved pairs of whole
processes, the import and the fit, timed by the wall clock. Prints each one's median, the
median of the pairs' ratios and their range. The machine's own speed moves both (on this
project's 2-core machine the import took 1.9-2.9 s over one day), so only a ratio measured
in one run means anything.

    .venv/bin/python benchmarks/startup.py --pairs 21
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _timed(command: list[str], env: dict, cwd: Path) -> float:
    start = time.perf_counter()
    subprocess.run(command, env=env, cwd=cwd, check=True, capture_output=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=15, help="interleaved pairs (default 15)")
    args = parser.parse_args()
    script = Path(sys.executable).with_name("ctjax")
    ctjax = [str(script)] if script.exists() else [sys.executable, "-m", "ctjax.cli"]
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        env = {**os.environ, "CTJAX_CACHE_DIR": str(work / "cache")}
        env.pop("CTJAX_NO_CACHE", None)
        synth = [*ctjax, "synth", "--width", "320", "--height", "256", "--frames", "5"]
        subprocess.run([*synth, "capture"], env=env, cwd=work, check=True)
        fit = [*ctjax, "fit", "capture", "--json", "fit.json"]
        imported = [sys.executable, "-c", "import ctjax, jax"]
        for _ in range(2):  # the first keeps the programs, the second writes what it used
            _timed(fit, env, work)
        times = {"import": [], "fit": []}
        for _ in range(args.pairs):
            times["import"].append(_timed(imported, env, work))
            times["fit"].append(_timed(fit, env, work))
    ratios = [f / i for f, i in zip(times["fit"], times["import"], strict=True)]
    print(f"{args.pairs} pairs, wall clock of whole processes")
    for name, seconds in times.items():
        print(f"  {name:6s} median {statistics.median(seconds):.3f} s")
    print(
        f"  fit / import: median {statistics.median(ratios):.3f}x "
        f"(pairs {min(ratios):.3f}-{max(ratios):.3f}x)"
    )


if __name__ == "__main__":
    main()
