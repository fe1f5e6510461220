"""Independent work on threads: one fit compiles while another runs, or runs while the
host analyses what the others gave.

JAX releases the GIL while it traces little and while XLA compiles and runs a program, so
fits of different models (diagnose's candidates, calibrate-light's falloff sets) overlap on
a machine's cores (`in_order`), and so does a fit with NumPy and OpenCV work that does not
need it (`started`: `fit`'s half-frame fits and sparkle density). Results do not depend on
the number of threads: each fit is the same program on the same data, only when it runs
changes.
"""

import concurrent.futures
import os
import threading
from collections.abc import Callable, Iterable, Iterator

from ._errors import ParameterError

# At most this many threads: on 2 cores one fit keeps ~1.5 of them busy (compiling, then
# running) and a second fills the gaps (a sinus diagnosis 245.6 -> 223.0 s); memory grows
# with each fit held at once.
MAX_WORKERS = 4


def default_workers() -> int:
    """The cores this process may use, at most `MAX_WORKERS`."""
    return max(1, min(MAX_WORKERS, len(os.sched_getaffinity(0))))


def checked_workers(workers: int | None) -> int:
    """`workers`, or `default_workers()` for None; a clear error for anything but a
    positive integer."""
    if workers is None:
        return default_workers()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ParameterError(f"workers must be a positive integer, got {workers!r}")
    return workers


def in_order(fn: Callable, items: Iterable, workers: int) -> Iterator:
    """`fn(item)` for every item on `workers` threads, yielded in the items' order as each
    is ready (an exception is raised where its item comes)."""
    items = list(items)
    if workers == 1 or len(items) < 2:
        yield from map(fn, items)
        return
    with concurrent.futures.ThreadPoolExecutor(min(workers, len(items))) as pool:
        yield from pool.map(fn, items)


def started(fn: Callable, *args) -> concurrent.futures.Future:
    """`fn(*args)` running on a thread of its own, beside what the caller does next; the
    future's `result()` waits for it and raises what it raised. A daemon thread: a command
    that fails before it asks for the result ends without waiting for it."""
    future = concurrent.futures.Future()

    def run():
        if future.set_running_or_notify_cancel():
            try:
                future.set_result(fn(*args))
            except BaseException as error:  # handed to whoever asks for the result
                future.set_exception(error)

    name = f"ctjax {getattr(fn, '__name__', 'task')}"
    threading.Thread(target=run, name=name, daemon=True).start()
    return future
