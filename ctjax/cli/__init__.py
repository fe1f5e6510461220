"""The `ctjax` command line (`ctjax synth`, `ctjax fit`, ... `ctjax batch`): `main` runs one
command from its words, `run` is the console script, `build_parser` the parser (of every
command, or of the one a command line names).

Bad input is reported on one line naming the problem (and the file), exit status 2, no
traceback.

This package is the top layer, and nothing in ctjax imports it. Each command's parser and
body are in `ctjax._commands`, below `ctjax.batch`, which runs some of them as its steps;
`batch`'s own are here (`_batch.py`), above `ctjax.batch`.
"""

import argparse
import sys

from .._commands import COMMANDS
from .._commands._runner import execute, parser_of
from ._batch import add_batch_parser


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every `ctjax` command, in the order `ctjax --help` lists them; given the
    name of one, of that command alone (what running it needs: building all ten parsers
    took 41 ms of a repeated `ctjax fit`'s 1.4 s, a few imports included)."""
    adders = {**COMMANDS, "batch": add_batch_parser}
    return parser_of([adders[command]] if command in adders else adders.values())


def main(argv: list[str] | None = None) -> int:
    """Run `ctjax ARGV` (`sys.argv[1:]` when None) in this process; returns the exit status:
    0, 2 for bad input (one line on stderr), 130 if interrupted."""
    words = sys.argv[1:] if argv is None else argv
    return execute(build_parser(words[0] if words else None), argv)


def run() -> None:
    """The `ctjax` console command: `main`, then the process ends without the interpreter's
    finalisation (`_exit`). The process is the command's: Python's cyclic garbage collector
    runs less often in it (tracing and loading programs allocate many short-lived objects:
    a cold test_diagnostics.py spent 3.9 s of 60 s collecting at the default thresholds,
    0.55 s at these; a repeated `ctjax fit` on 320x256 x 5, 2.95-3.35 s -> 2.86-2.99 s)."""
    import gc

    gc.set_threshold(100_000, 50, 100)
    _exit(main())


def _exit(code: int) -> None:
    """End the process with `code` once the `atexit` handlers have run (temporary folders,
    logging, Dask) and the outputs are flushed, skipping the interpreter's finalisation:
    with JAX loaded, tearing down its ~1000 modules and their objects takes 0.15-0.3 s on
    this project's 2-core machine, a seventh of a repeated `ctjax fit`. A command that
    leaves a non-daemon thread running exits normally (finalisation joins it)."""
    import atexit
    import os
    import threading

    running = [
        t
        for t in threading.enumerate()
        if t is not threading.main_thread() and not t.daemon and t.is_alive()
    ]
    run_exit_functions = getattr(atexit, "_run_exitfuncs", None)
    if running or run_exit_functions is None:
        sys.exit(code)
    run_exit_functions()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    os._exit(code)
