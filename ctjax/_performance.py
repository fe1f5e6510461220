"""Process-level settings that matter for throughput on CPU."""

import ctypes
import functools
import os
from pathlib import Path

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8


@functools.cache
def tune_malloc() -> bool:
    """Keep freed large buffers in the heap instead of returning them to the OS.

    XLA allocates a fresh output buffer per call; with glibc's defaults a frame-sized buffer
    is mmapped and unmapped every call, and its first touch page-faults every page. On a
    2-core machine this halved the renderer's throughput at 1920x1080. One arena for every
    thread, too: a thread of XLA's that got an arena of its own allocates from mmapped heaps
    that glibc unmaps once empty, whatever the thresholds (the renderer then ran at 115-200
    Mpix/s in some processes and 280-360 in others, 1200-8500 page faults a call against
    0-1500; with one arena 285-387 in each of 5 processes). Call it before JAX's first
    computation (its threads choose their arena then). Returns True when the settings
    were applied (glibc only; a no-op elsewhere). Called by the command-line interface and
    the benchmarks; libraries embedding ctjax may call it themselves.
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
        ok_mmap = libc.mallopt(_M_MMAP_THRESHOLD, 1 << 30)
        ok_trim = libc.mallopt(_M_TRIM_THRESHOLD, (1 << 31) - 1)
        ok_arena = libc.mallopt(_M_ARENA_MAX, 1)
    except (OSError, AttributeError):
        return False
    return bool(ok_mmap and ok_trim and ok_arena)


# XLA's CPU code generator prefers 256-bit vectors, even where the CPU has 512-bit ones.
VECTOR_WIDTH_FLAG = "--xla_cpu_prefer_vector_width"


def _has_avx512() -> bool:
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("flags"):
                    return "avx512f" in line.split()
    except OSError:
        pass
    return False


@functools.cache
def tune_xla() -> bool:
    """Let XLA's CPU code use 512-bit vectors where the CPU has them (AVX-512).

    XLA generates 256-bit code by default, even on AVX-512 CPUs (wide vectors slowed the
    clock of older Intel cores). On the AMD EPYC (Zen 4) of the benchmarks, 512-bit code
    rendered 1920x1080 frames 10-25% faster (`benchmarks/render.py`, alternating
    processes); the fits ran as before (`benchmarks/albedo_map.py`; identical
    `ctjax fit` results). Appends `--xla_cpu_prefer_vector_width=512` to `XLA_FLAGS`
    unless that variable already sets the width (yours is kept); XLA reads it when its
    backend starts, so call this before JAX's first computation. Returns True when the
    flag was added. Called by the command-line interface and `benchmarks/render.py`.
    """
    from jax._src import xla_bridge

    flags = os.environ.get("XLA_FLAGS", "")
    if VECTOR_WIDTH_FLAG in flags or xla_bridge.backends_are_initialized():
        return False
    if not _has_avx512():
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {VECTOR_WIDTH_FLAG}=512".strip()
    return True


# The command line keeps XLA's compiled programs here between runs (`enable_compilation_cache`).
CACHE_ENV = "CTJAX_CACHE_DIR"
NO_CACHE_ENV = "CTJAX_NO_CACHE"


def compilation_cache_dir() -> Path | None:
    """Where the command line keeps compiled programs: `$CTJAX_CACHE_DIR`, else
    `$XDG_CACHE_HOME/ctjax/jax`, else `~/.cache/ctjax/jax`; None when `$CTJAX_NO_CACHE` is
    set to anything but "" or "0"."""
    import os
    from pathlib import Path

    if os.environ.get(NO_CACHE_ENV, "") not in ("", "0"):
        return None
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "ctjax" / "jax"


def enable_compilation_cache(folder: Path | None = None) -> Path | None:
    """JAX's persistent compilation cache in `folder` (default `compilation_cache_dir()`):
    a repeated command loads its compiled programs instead of compiling them again (the
    fitters take seconds to compile and milliseconds to run). Leaves a cache the user set
    through JAX's own `JAX_COMPILATION_CACHE_DIR` as it is, and keeps the traced programs
    beside it (`ctjax._programs`) when it is a local folder of the user's alone. The folder
    is created for the user alone (0700); one that another user can write is not used, with
    a warning: its compiled programs are machine code that whoever writes them chooses.
    Returns the folder in use (None: off)."""
    import jax

    from ._private_files import private_folder
    from ._programs import keep_programs

    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        # JAX's own cache, as the user set it: the traced programs beside it, when it is a
        # local folder for the user alone.
        jax_folder = jax.config.jax_compilation_cache_dir
        if jax_folder and "://" not in str(jax_folder):
            jax_folder = Path(jax_folder).expanduser()
            if private_folder(jax_folder):
                keep_programs(jax_folder / "programs")
        return jax.config.jax_compilation_cache_dir
    folder = compilation_cache_dir() if folder is None else folder
    if folder is None:
        return None
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError:
        return None  # a read-only home: compile every time, as without the cache
    if not private_folder(folder):
        return None  # a shared or group folder: compile every time (warned)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    keep_programs(folder / "programs")  # the traced programs too (`ctjax._programs`)
    return folder
