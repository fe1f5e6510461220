import atexit
import functools
import gc
import hashlib
import os
import sys
import tempfile
from pathlib import Path

import jax
import numpy as np
import pytest

# float64 by default in the tests; float32 paths are exercised explicitly (see helpers.cast).
jax.config.update("jax_enable_x64", True)

# Python's cyclic garbage collector less often: tracing and lowering allocate millions of
# short-lived objects, and the default thresholds (700, 10, 10) ran it 2948 times in a cold
# test_diagnostics.py, 3.9 s of its 60 s; at (100000, 50, 100) 12 times, 0.55 s (the same
# as `ctjax.cli.run` does for a command).
gc.set_threshold(100_000, 50, 100)

# One persistent compilation cache for the test session and everything it starts (the CLI
# subprocesses): the same fitters compile once, not once per process.
_CACHE = Path(__file__).resolve().parent.parent / ".jax_cache"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_CACHE))
# Every program, however quick to compile: the two workers run different files that share
# fitters (a diagnose compiles ~108 programs of 0.05-0.5 s each); test_notebooks' diagnose
# after test_diagnostics' in another process: 31.9 -> 25.3 s (the suite: 493 -> 477 s, cold,
# one run each, within the run-to-run spread).
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update(
    "jax_persistent_cache_min_compile_time_secs",
    float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]),
)

# XLA:CPU's loop emitters instead of its newer fusion emitters, for the test session and its
# subprocesses (set before the backend starts). Most of the suite's time is compiling
# distinct fitter programs: with the loop emitters the whole suite compiles 114 s instead of
# 176 s (337 s -> 269 s in all, cold cache, 2 cores) and the near-light LM runs 2.1 s instead
# of 3.1 s, with the same results. Not a library default: the renderer is 4-7x slower
# with them (`benchmarks/render.py`, which checks it against NumPy under XLA's defaults).
#
# And LLVM's optimisation level 0 for the same reason (the tests' programs run for
# milliseconds and compile for seconds): 301-307 s -> 281-296 s for the suite, cold
# cache, fresh clone, 2 cores, the same results.
# Measured again at 29eea85 (619 tests, cold cache, 2 cores): level 1 makes the diagnose
# fits 7x faster (a 128x96 x 5 diagnosis 11.8 -> 1.6 s warm) and the compiles 1.7x slower;
# the suite took 483 s, as at level 0 (413-487 s). Compiling is 60% of the suite's CPU time
# (backend 464 s, tracing 115 s, lowering 94 s of 1109 s, jax.monitoring per file), in
# hundreds of distinct programs; the persistent cache saved 22 s.
# Measured again at 6257313 (633 tests, cold, 2 cores, one run each): level 0 431.05 s (803
# CPU-s), level 1 431.04 s (812 CPU-s); XLA's default level with
# --xla_llvm_disable_expensive_passes 444 s at 76298e0 (level 0 there: 453.7 s). Kept at 0.
# A whole-suite profile (one process, cProfile) put 2815 compiled programs at 149 s of XLA
# compiling, 149 s of tracing and 78 s of lowering (both inflated by the profiler), ~167 s of
# running them; synthesising the test captures 104 s (ray casting 64 s of it, cut 4x since).
# And no parallel code generation: XLA splits each program's LLVM module to compile the parts
# on threads, but the workers already keep both cores busy, and splitting costs: a cold
# `diagnose` (128x96 x 5, 108 programs) compiles in 12.8-13.2 s instead of 15.7-16.3 s.
# And each program run on one thread: the two workers each started a thread pool of both
# cores for programs that run for milliseconds, and the pools' threads competed (warm cache,
# test_calibration.py beside test_diagnostics.py, two processes on 2 cores: 58-63 s, 105-114
# CPU-s -> 50-55 s, 89-98 CPU-s; the suite at 9dbbb11, cold, fresh clone, 2 cores, one run
# each: 612.2 s / 1165 CPU-s -> 566.2 s / 1076 CPU-s, the same 907 passed).
_TEST_FLAGS = {
    "--xla_cpu_use_fusion_emitters": "false",
    "--xla_backend_optimization_level": "0",
    "--xla_cpu_parallel_codegen_split_count": "1",
    "--xla_cpu_multi_thread_eigen": "false",
    "intra_op_parallelism_threads": "1",
}
for _flag, _value in _TEST_FLAGS.items():
    if _flag not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_flag}={_value}".strip()

# ...but the Levenberg-Marquardt fitters at LLVM level 1: they run more than they compile
# (the suite runs the pixel fitter 619 times, 84 s at level 0, for 101 programs). At 3372858
# (707 tests, cold, fresh clone, 2 cores): 332.0 s / 610 CPU-s at level 0 everywhere,
# 316.6 s / 581 CPU-s with the pixel fitter at level 1; warm, test_diagnostics.py 41-48 s ->
# 24-26 s. The map's branch and bound (60 programs for 106 runs) stays at 0.
# So does the facets' marginal likelihood (its test 14.2 -> 10.6 s, tests/test_facets.py 42.3
# -> 39.1 s cold); the other facet programs at level 1 cost more compiling than they saved.
_LONG_RUNNING = (
    "ctjax.fitting._fit._least_squares",
    "ctjax.fitting._map_least_squares._least_squares",
    "ctjax.fitting._facet_marginal._marginal",
)


@pytest.fixture(autouse=True, scope="session")
def _long_running_programs_optimised():
    from ctjax import _programs

    for name in _LONG_RUNNING:
        _programs.PROGRAM_OPTIONS[name] = {"xla_backend_optimization_level": 1}
    yield


# File order: CI runs `--dist loadfile`, one file per worker at a time, and pytest-xdist
# (>= 3.6) hands out the files with the most tests first. Measured against the slowest
# files first (worker-seconds: diagnostics, sfm, calibration, estimation, ...), alternating,
# cold caches, 2 workers: xdist's order 291 and 306 s, slowest first 326 and 341 s, although
# slowest first ended the two workers within 1.3 s of each other where xdist's left one idle
# for 19 s (likely: the files share compiled programs through the persistent cache above,
# and heavy files started together each compile the same fitters). xdist's order is kept.
#
# pytest-xdist's `--dist worksteal` (tests handed out in contiguous chunks, an idle worker
# taking from the other) instead of `loadfile`: at 61f81a5 (873 tests, cold, fresh clone,
# 2 cores) 375.4 s against loadfile's 374.7 s the run before: the same. loadfile is kept.
#
# Workers: more than the cores does not pay either. At 79c0fba (656 tests, cold, 2 cores,
# `pytest_xdist_auto_num_workers` returning 2, 3 or 4): 2 workers 462.5 s, 3 workers 437.7
# and 476.2 s, 4 workers 499.0 s: within the run-to-run spread at 3, worse at 4. -n auto.
#
# `benchmarks/suite_time.py` measures what follows (per file, test and compiled program, cold);
# its latest figures and what did not cut them: benchmarks/README.md.
#
# Where the time goes, at 1abb1a4 (735 tests, cold, fresh clone, 2 cores: 468 s, 15 CPU-min;
# per-test jax.monitoring events): compiling is 59% of the CPU time (XLA 35%, tracing 13%,
# lowering 11%), in ~2300 distinct programs. The kept programs (`persistent_jit`) are 409
# distinct keys, mostly one (function, model, static options) at several shapes: the branch
# and bound's `_fit` alone at 16 (frames 2-8 x points 256-16384, the test captures' sizes).
# With the sample counts symbolic they would be 304 (their tracing saved: an estimated 30-50
# of the ~580 CPU-s compiling). Measured and not a gain: the API's near-light tests at the
# command's sample counts (programs shared, other fits slower: test_calibration.py 113 -> 127
# CPU-s); LLVM level 0 for the Levenberg-Marquardt programs (113 -> 135 CPU-s there); XLA's
# --xla_cpu_enable_concurrency_optimized_scheduler=false or --xla_cpu_use_xnnpack=false (a
# cold near-light calibration and fit: 29-31 CPU-s either way); keeping synthesised captures
# (68 syntheses, 56 distinct, 46 CPU-s: 6 s repeated), the demo at 3 frames (65 -> 64 CPU-s).
#
# Again at 674c7fc (788 tests, cold, fresh clone, 2 cores: 419-443 s; 7c21db8, the last of
# 2026-11-28, 731 tests: 360 s the same day). Per test (jax.monitoring): 812 worker-s, XLA
# compiling 267, tracing 93, lowering 84. XLA by program: the two LM fitters'
# `_least_squares` 132 s in 106 compilations, the branch and bound's `_fit` 42 s in 61,
# `_started` 16 s in 58. The kept programs are 481 keys, nearly all a distinct (function,
# model, static options): `_fit._least_squares` 38 keys in 34 of them, the map's 47 in 30,
# so the same shapes everywhere would merge few. Running the kept programs (every call
# after their first) takes 86 s in all. The JAX compilation cache on or off: the same
# (test_calibration.py 68.9 / 68.3 s). What is left to cut is the number of distinct models.


# The traced programs too (`ctjax._programs`), in the same folder: the two workers, and the
# commands the tests start, share the traced fitters instead of tracing each again (the
# command line does the same beside a `JAX_COMPILATION_CACHE_DIR`). Set per test: the tests
# of `ctjax._programs` set their own folder and turn it off after them.
def _textures_kept_on_disk():
    """The synthetic captures' tissue textures (`ctjax.synth._texture`), one file per seed in
    the cache folder: the suite synthesises about 90 captures from 6 seeds, and each process
    made the 2048 x 2048 texture of a seed again (1.5 s each: 17 times, 26 worker-seconds
    of a cold suite). Keyed by the texture module's source and the libraries that draw it,
    so a changed texture is made anew; the same bytes as made in the process."""
    import cv2

    from ctjax.synth import _texture

    make = _texture._texture_of.__wrapped__
    source = Path(_texture.__file__).read_bytes()
    versions = f"{np.__version__} {cv2.__version__}".encode()
    folder = _CACHE / "textures"

    @functools.lru_cache(maxsize=3)
    def texture_of(entropy, spawn_key, pool_size):
        key = hashlib.sha256(source + versions + repr((entropy, spawn_key, pool_size)).encode())
        path = folder / f"{key.hexdigest()[:32]}.npy"
        try:
            texture = np.load(path)
        except (OSError, ValueError):
            texture = make(entropy, spawn_key, pool_size)
            try:  # whole files only (the other worker may read it); unwritable: not kept
                folder.mkdir(parents=True, exist_ok=True)
                with tempfile.NamedTemporaryFile(dir=folder, suffix=".npy", delete=False) as part:
                    np.save(part, texture)
                os.replace(part.name, path)
            except OSError:
                pass
        texture.setflags(write=False)
        return texture

    _texture._texture_of = texture_of


_textures_kept_on_disk()


# Two tiers. The README's test command (CI's `.ci/run`) runs the tests not marked `slow`:
# every module's checks, every command once end to end on a small synthetic capture, every
# refusal of bad input, and the diagnosis loop naming each hidden effect
# (tests/test_diagnostics.py). `pytest --slow` runs the slow tier as well (`pytest --slow -m
# slow` only it): the measurements that take 5 s or more cold, the same commands with every
# option on larger captures, the fits on real frames, the demo's whole pipeline. A test
# named on the command line (`pytest tests/test_real.py::test_...`) runs whatever its tier.
# Why: the whole suite took 589-634 s cold on the 2-core machine in eleven runs on
# 2026-12-07, twice the 5 minutes the tests have. The fast tier, cold, from a fresh clone:
# 864 tests in 287.7 and 279.6 s; the slow tier alone, 60 tests then, 488.6 s
# (docs/design.md, "Two tiers of tests"; benchmarks/README.md, "The test suite's time").
# A test belongs in the slow tier when it takes 5 s or more cold and another fast test
# already runs its command.
SLOW_TIER = "the slow tier: `pytest --slow` runs it"


def pytest_addoption(parser):
    parser.addoption(
        "--slow", action="store_true", help="also run the tests marked slow (tests/conftest.py)"
    )


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "slow: the slow tier, run by `pytest --slow` (tests/conftest.py)"
    )


def pytest_collection_modifyitems(config, items):
    if config.getoption("--slow") or "slow" in (config.option.markexpr or ""):
        return
    named = [arg for arg in config.args if "::" in arg]
    slow = [
        item
        for item in items
        if item.get_closest_marker("slow")
        and not any(item.nodeid in a or a in item.nodeid for a in named)
    ]
    if slow:
        kept = set(map(id, slow))
        items[:] = [item for item in items if id(item) not in kept]
        config.hook.pytest_deselected(items=slow)


def pytest_terminal_summary(terminalreporter, config):
    if not (config.getoption("--slow") or "slow" in (config.option.markexpr or "")):
        terminalreporter.write_line(f"tests marked slow not run ({SLOW_TIER})")


def _exit_now():
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(0)


def pytest_unconfigure(config):
    """An xdist worker ends without the interpreter's finalisation (as the `ctjax` command
    does, `ctjax.cli._exit`): its results are with the controller by then, and tearing down
    a process that ran hundreds of tests' programs is on the suite's critical path, since the
    controller waits for its workers before it reports. Registered last, run first of the
    `atexit` handlers."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        atexit.register(_exit_now)


@pytest.fixture(autouse=True)
def _kept_programs():
    from ctjax import _programs

    _programs.keep_programs(_CACHE / "programs")
    yield
    _programs.keep_programs(None)


@pytest.fixture
def coarse_facets(monkeypatch):
    """The facet estimators on coarse grids (`HeldOutTracks.facet_lobe` and
    `.facet_marginal`), for the commands' wiring tests: the estimators themselves are
    tests/test_facets.py's. The wiring of `fit --facets --facet-marginal` took 33 s of a warm
    test_albedo_map.py's 66 with the default grids (9 sigmas, 2 halves; 8 spreads)."""
    from ctjax.heldout import HeldOutTracks

    lobe, marginal = HeldOutTracks.facet_lobe, HeldOutTracks.facet_marginal
    sigmas, F_tildes = (0.1, 0.2, 0.3), (0.02, 0.05, 0.1)

    def coarse_lobe(self, light, **options):
        grids = dict(sigmas=sigmas, F_tildes=F_tildes, refine_steps=0)
        return lobe(self, light, **dict(grids, **options))

    def coarse_marginal(self, light, **options):
        grids = dict(sigmas=sigmas, F_tildes=F_tildes, nodes=(6, 3), refine=2)
        grids.update(prior_sigmas=(0.1, 0.3, 1.0))
        return marginal(self, light, **dict(grids, **options))

    monkeypatch.setattr(HeldOutTracks, "facet_lobe", coarse_lobe)
    monkeypatch.setattr(HeldOutTracks, "facet_marginal", coarse_marginal)
    return dict(sigmas=sigmas, F_tildes=F_tildes)
