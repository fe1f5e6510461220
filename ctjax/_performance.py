"""Process-level settings that matter for throughput on CPU."""

import ctypes
import functools

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


@functools.cache
def tune_malloc() -> bool:
    """Keep freed large buffers in the heap instead of returning them to the OS.

    XLA allocates a fresh output buffer per call; with glibc's defaults a frame-sized buffer
    is mmapped and unmapped every call, and its first touch page-faults every page. On a
    2-core machine this halved the renderer's throughput at 1920x1080. Returns True when
    the settings were applied (glibc only; a no-op elsewhere). Called by the command-line
    interface and the benchmarks; libraries embedding ctjax may call it themselves.
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
        ok_mmap = libc.mallopt(_M_MMAP_THRESHOLD, 1 << 30)
        ok_trim = libc.mallopt(_M_TRIM_THRESHOLD, (1 << 31) - 1)
    except (OSError, AttributeError):
        return False
    return bool(ok_mmap and ok_trim)
