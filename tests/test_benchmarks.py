"""The benchmarks (not part of the suite: they measure, on minutes of real data) still import
against the library as it is: a name moved or renamed in ctjax fails here, not months later
when someone runs one (benchmarks/nearest_view.py imported `OTHER_VIEWS_SHARE` from where it
no longer was)."""

import importlib
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


@pytest.fixture
def on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))  # they import each other and `_results`
    yield
    for name in [
        n for n, m in sys.modules.items() if str(BENCHMARKS) in str(getattr(m, "__file__", ""))
    ]:
        del sys.modules[name]


def test_every_benchmark_imports(on_path):
    scripts = sorted(BENCHMARKS.glob("*.py"))
    assert len(scripts) > 40
    failed = {}
    for script in scripts:
        try:
            module = importlib.import_module(script.stem)
        except Exception as error:  # every failure, reported by name
            failed[script.name] = repr(error)
            continue
        if not script.stem.startswith("_"):
            assert module.__doc__, f"{script.name} says what it measures in its docstring"
    assert not failed, failed
