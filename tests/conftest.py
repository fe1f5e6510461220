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
