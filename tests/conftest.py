import os
from pathlib import Path

import jax

# float64 by default in the tests; float32 paths are exercised explicitly (see helpers.cast).
jax.config.update("jax_enable_x64", True)

# One persistent compilation cache for the test session and everything it starts (the CLI
# subprocesses): the same fitters compile once, not once per process.
_CACHE = Path(__file__).resolve().parent.parent / ".jax_cache"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_CACHE))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
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
_TEST_FLAGS = {"--xla_cpu_use_fusion_emitters": "false", "--xla_backend_optimization_level": "0"}
for _flag, _value in _TEST_FLAGS.items():
    if _flag not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_flag}={_value}".strip()

# The slowest files first (worker-seconds per file, cold cache, 2 workers: diagnostics 72,
# sfm 61, calibration 53, estimation 51, albedo_map 44, cli 43, light_field 40, evaluation
# 30, lobes 20, notebooks 15, synth 14, video 9, render 9, batch 8; the rest under 7). CI
# runs `--dist loadfile`, one file per worker at a time in collection order: a long file
# collected last keeps one worker busy while the other waits.
_SLOWEST_FIRST = [
    f"test_{name}.py"
    for name in (
        "diagnostics",
        "sfm",
        "calibration",
        "estimation",
        "albedo_map",
        "cli",
        "light_field",
        "evaluation",
        "lobes",
        "notebooks",
        "synth",
        "video",
        "render",
        "batch",
    )
]


def pytest_configure(config):
    # pytest-xdist >= 3.6 hands out files by their number of tests, most first, unless told
    # not to: it ran lobes (many small tests) first and calibration last (269.6 s, one
    # worker idle for the last 19 s).
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(_SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: files stay whole
