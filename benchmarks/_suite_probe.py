"""A pytest plugin for `benchmarks/suite_time.py`: what each test spends tracing, lowering and
compiling, per program.

Loaded with `-p _suite_probe` (this folder on PYTHONPATH). A `jax.monitoring` listener adds
up the durations JAX reports for every program it traces (`jaxpr_trace_duration`), lowers
(`jaxpr_to_mlir_module_duration`) and compiles (`backend_compile_duration`), by test and by
program name; each pytest process (an xdist worker) writes them to
`$CTJAX_SUITE_PROBE_DIR/<worker>.json` when it ends.
"""

import collections
import json
import os
from pathlib import Path

import jax.monitoring

_EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}
_by_program = collections.defaultdict(lambda: [0, 0.0])  # (stage, program) -> [count, s]
_by_test = collections.defaultdict(float)  # (stage, test) -> s
_test = ["(outside a test)"]


def _listener(event, duration, **kwargs):
    stage = _EVENTS.get(event)
    if stage is None:
        return
    name = str(kwargs.get("fun_name", "?")).removeprefix("jit(").removesuffix(")")
    entry = _by_program[(stage, name)]
    entry[0] += 1
    entry[1] += duration
    _by_test[(stage, _test[0])] += duration


jax.monitoring.register_event_duration_secs_listener(_listener)


def pytest_runtest_setup(item):
    _test[0] = item.nodeid


def pytest_unconfigure(config):
    folder = os.environ.get("CTJAX_SUITE_PROBE_DIR")
    if not folder:
        return
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    data = {
        "programs": [[s, p, n, d] for (s, p), (n, d) in _by_program.items()],
        "tests": [[s, t, d] for (s, t), d in _by_test.items()],
    }
    (Path(folder) / f"{worker}.json").write_text(json.dumps(data))
