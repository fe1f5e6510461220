"""What a cold `diagnose` spends compiling, program by program, and its warm time.

    python benchmarks/diagnose_compile.py [CAPTURE] [--test-flags] [--workers 1]

Runs `diagnose` on CAPTURE (made by `ctjax synth` at 128x96 x 5 frames with an
inverse-square falloff when the folder does not exist) with seven candidates, first with one
albedo, then with the albedo map; each twice in this process: cold (nothing kept:
`CTJAX_NO_CACHE`, no compilation cache) and warm. Prints the seconds of each, the verdicts,
and XLA's compile seconds per program name (summed from JAX's "Finished XLA compilation"
messages). `--test-flags`: the test session's XLA flags and the LM fitters at LLVM level 1
(tests/conftest.py), to measure what the suite pays.

Measured (2-core VM, 2026-11-28, `--test-flags`, interleaved runs): the 16 LM programs
(`_least_squares`) 14.5 / 12.8 s at 0f7c5a8 against 16.5 / 14.8 s at f239fa1 (the
solution's residuals after the loop dropped: the aux comes from the loop); this VM's speed
drifts by a fifth within hours, so compare only runs side by side.
"""

import argparse
import collections
import logging
import os
import re
import sys
import time

_TEST_FLAGS = (
    "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=0 "
    "--xla_cpu_parallel_codegen_split_count=1"
)
_CANDIDATES = (
    "albedo_texture",
    "light_offset",
    "inverse_square",
    "camera_gamma",
    "ggx",
    "frame_exposure",
    "oren_nayar",
)


class _CompileSeconds(logging.Handler):
    """XLA's compile seconds per program name, from JAX's log messages."""

    PATTERN = re.compile(r"Finished XLA compilation of (.*?) in ([\d.e-]+) sec")

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.seconds = collections.defaultdict(lambda: [0, 0.0])

    def emit(self, record):
        match = self.PATTERN.search(record.getMessage())
        if match:
            name = re.sub(r"^jit\((.*)\)$", r"\1", match.group(1))
            self.seconds[name][0] += 1
            self.seconds[name][1] += float(match.group(2))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", nargs="?", default="/tmp/ctjax-diagnose-compile")
    parser.add_argument("--test-flags", action="store_true")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    if args.test_flags:
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_TEST_FLAGS}".strip()
    os.environ["CTJAX_NO_CACHE"] = "1"

    import jax

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_log_compiles", True)
    handler = _CompileSeconds()
    logger = logging.getLogger("jax")
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    logger.propagate = False

    from _results import emit

    from ctjax import _programs
    from ctjax.diagnostics import diagnose
    from ctjax.diagnostics._candidates import CANDIDATES
    from ctjax.io import load_capture
    from ctjax.synth import SynthOptions, synthesize

    if args.test_flags:
        for name in (
            "ctjax.fitting._fit._least_squares",
            "ctjax.fitting._map_least_squares._least_squares",
        ):
            _programs.PROGRAM_OPTIONS[name] = {"xla_backend_optimization_level": 1}
    if not os.path.exists(args.capture):
        options = SynthOptions(
            width=128, height=96, frames=5, seed=3, effects={"inverse_square": True}
        )
        synthesize(args.capture, options)
    capture = load_capture(args.capture)
    few = tuple(c for c in CANDIDATES if c.name in _CANDIDATES)
    settings = dict(max_samples=3000, heldout_samples=6000, workers=args.workers)
    for albedo in ("uniform", "map"):
        seconds = []
        for _ in range(2):
            start = time.perf_counter()
            diagnosis = diagnose(capture, candidates=few, albedo=albedo, **settings)
            seconds.append(time.perf_counter() - start)
        ranked = ", ".join(
            f"{c.details['effect']} {c.heldout_rmse:.4f}" for c in diagnosis.candidates
        )
        print(
            f"{albedo}: cold {seconds[0]:.1f} s, warm {seconds[1]:.1f} s; verdict "
            f"{diagnosis.verdict}, base {diagnosis.base_rmse:.4f} levels; {ranked}"
        )
        emit({"albedo": albedo, "cold_s": seconds[0], "warm_s": seconds[1],
              "verdict": diagnosis.verdict, "test_flags": args.test_flags})  # fmt: skip
    print(f"{'compilations':>12} {'seconds':>8}  program")
    for name, (count, total) in sorted(handler.seconds.items(), key=lambda x: -x[1][1])[:8]:
        print(f"{count:>12} {total:8.2f}  {name}")
    lm = handler.seconds.get("_least_squares", [0, 0.0])
    emit({"lm_compilations": lm[0], "lm_compile_s": lm[1], "test_flags": args.test_flags})
    return 0


if __name__ == "__main__":
    sys.exit(main())
