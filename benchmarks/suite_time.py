"""Where the test suite's time goes: per file, per test, and per compiled program.

    .venv/bin/python benchmarks/suite_time.py [--warm] [--top 15] [-- PYTEST_ARGS ...]

Runs the README's test command (`pytest -q -n auto --maxprocesses 4 --dist loadfile`) with
`--durations=0` and the plugin `benchmarks/_suite_probe.py`, which adds up what JAX reports
tracing, lowering and compiling, per test and per program. Cold by default, as CI runs it:
the tests' cache folder (`.jax_cache`: XLA's programs, the kept traced programs, the
synthetic textures) is removed first; `--warm` keeps it. PYTEST_ARGS (after `--`) replace the
test selection, e.g. `-- tests/test_calibration.py`; `-- --slow` times both tiers (the
README's command runs the fast one: tests/conftest.py).

Prints the suite's wall time, the worker-seconds per file, the slowest tests with their
seconds of compiling, and the programs that compile longest (how many times, how long,
tracing and lowering beside). One JSON line (`emit`) carries the totals.

Measured (2-core VM, 2026-12-04, cold, 864 tests at ca096a9): 305-321 s in five runs;
600 worker-seconds of which XLA compiling 184, tracing 66, lowering 60; the LM fitter's
`_least_squares` 72 s of compiling in 99 programs (benchmarks/README.md, "The test suite's
time").
"""

import argparse
import collections
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _results import emit

ROOT = Path(__file__).resolve().parents[1]
_DURATION = re.compile(r"^\s*([\d.]+)s (setup|call|teardown)\s+(\S+?)::(\S+)")


def _run(pytest_args, probe: Path) -> tuple[float, str, int]:
    env = dict(os.environ, CTJAX_SUITE_PROBE_DIR=str(probe))
    env["PYTHONPATH"] = os.pathsep.join(
        filter(None, [str(ROOT / "benchmarks"), env.get("PYTHONPATH")])
    )
    argv = [sys.executable, "-m", "pytest", "-q", "-n", "auto", "--maxprocesses", "4"]
    argv += ["--dist", "loadfile", "--durations=0", "-p", "_suite_probe", *pytest_args]
    started = time.perf_counter()
    done = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True)
    return time.perf_counter() - started, done.stdout + done.stderr, done.returncode


def _durations(output: str) -> dict[str, float]:
    """Seconds per test (setup, call and teardown together), from `--durations=0`."""
    seconds = collections.Counter()
    for line in output.splitlines():
        match = _DURATION.match(line)
        if match:
            seconds[f"{match.group(3)}::{match.group(4)}"] += float(match.group(1))
    return seconds


def _probed(probe: Path):
    programs = collections.defaultdict(lambda: collections.defaultdict(lambda: [0, 0.0]))
    tests = collections.defaultdict(collections.Counter)
    for path in probe.glob("*.json"):
        data = json.loads(path.read_text())
        for stage, program, count, seconds in data["programs"]:
            programs[program][stage][0] += count
            programs[program][stage][1] += seconds
        for stage, test, seconds in data["tests"]:
            tests[test][stage] += seconds
    return programs, tests


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warm", action="store_true", help="keep the tests' cache folder")
    parser.add_argument("--top", type=int, default=15)
    parser.add_argument("pytest_args", nargs="*", help="after --: the test selection")
    args = parser.parse_args()
    if not args.warm:
        shutil.rmtree(ROOT / ".jax_cache", ignore_errors=True)
    with tempfile.TemporaryDirectory() as folder:
        wall, output, status = _run(args.pytest_args, Path(folder))
        programs, tests = _probed(Path(folder))
    summary = [line for line in output.splitlines() if re.search(r"\d+ (passed|failed)", line)]
    print(f"{summary[-1] if summary else 'no summary'}; {wall:.1f} s wall (status {status})")
    seconds = _durations(output)
    by_file = collections.Counter()
    for test, s in seconds.items():
        by_file[test.split("::")[0]] += s
    stages = collections.Counter()
    for per_stage in programs.values():
        for stage, (_, s) in per_stage.items():
            stages[stage] += s
    print(
        f"worker-seconds {sum(seconds.values()):.1f}: compiling {stages['compile']:.1f}, "
        f"tracing {stages['trace']:.1f}, lowering {stages['lower']:.1f}"
    )
    print("\nworker-seconds per file")
    for name, s in by_file.most_common(args.top):
        print(f"  {s:7.1f}  {name}")
    print("\nslowest tests (seconds; of them compiling, tracing and lowering)")
    for test, s in seconds.most_common(args.top):
        spent = sum(tests.get(test, {}).values())
        print(f"  {s:7.1f}  ({spent:5.1f})  {test}")
    print("\nprograms by compiling seconds (count), tracing and lowering seconds")
    ranked = sorted(programs.items(), key=lambda item: -item[1]["compile"][1])
    for name, per_stage in ranked[: args.top]:
        count, compiling = per_stage["compile"]
        print(
            f"  {compiling:7.1f} ({count:4d})  trace {per_stage['trace'][1]:6.1f}  "
            f"lower {per_stage['lower'][1]:6.1f}  {name}"
        )
    emit(
        {
            "benchmark": "suite_time",
            "cold": not args.warm,
            "wall_s": round(wall, 1),
            "status": status,
            "worker_s": round(sum(seconds.values()), 1),
            **{f"{stage}_s": round(s, 1) for stage, s in stages.items()},
        }
    )
    return status


if __name__ == "__main__":
    sys.exit(main())
