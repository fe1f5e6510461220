"""Every notebook runs top to bottom (at a small size), so none of them rots, and says
what it is there to show.

The cells run in this process, in one namespace per notebook, as a kernel would run them:
the functions they call are then compiled once for the whole test session (a kernel is a
fresh process that traces and compiles everything again, ~20 s per notebook).
"""

import contextlib
import io
import re
from pathlib import Path

import matplotlib
import nbformat
import pytest

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


def _check_rendering(text: str) -> None:
    # The render of the true model reproduces the synthetic capture up to its noise.
    rmse = float(re.search(r"RGB RMSE: ([0-9.]+) levels", text).group(1))
    assert rmse < 1.5, text


def _check_diagnose(text: str) -> None:
    # The hidden effect (a light 6 mm off the lens) is named, and nothing else after it.
    assert "verdict: light_offset" in text, text
    assert "verdict on the rest: none" in text, text


def _check_retro(text: str) -> None:
    # The retro-reflection lobe at least halves Cook-Torrance's RMSE, in the data's unit.
    ratio = float(re.search(r"RMSE [0-9.]+ 1/sr, ([0-9]+)% of Cook-Torrance", text).group(1))
    assert ratio <= 50, text


CHECKS = {
    "01_rendering.ipynb": _check_rendering,
    "02_diagnose.ipynb": _check_diagnose,
    "03_measured_retro.ipynb": _check_retro,
}


# The diagnosis loop's notebook is the slow tier's (tests/conftest.py): the loop itself is
# tests/test_diagnostics.py's.
SLOW = {"02_diagnose.ipynb"}


@pytest.mark.parametrize(
    "path",
    [
        pytest.param(p, id=p.name, marks=[pytest.mark.slow] if p.name in SLOW else [])
        for p in NOTEBOOKS
    ],
)
def test_notebook_runs(path, tmp_path, monkeypatch):
    monkeypatch.setenv("CTJAX_NOTEBOOK_WIDTH", "96")
    monkeypatch.setenv("CTJAX_NOTEBOOK_SAMPLES", "3000")  # as test_diagnostics' SAMPLES
    monkeypatch.chdir(tmp_path)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    notebook = nbformat.read(path, as_version=4)
    namespace = {"__name__": "__main__"}
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        for index, cell in enumerate(notebook.cells):
            if cell.cell_type == "code":
                exec(compile(cell.source, f"{path.name}, cell {index}", "exec"), namespace)
    plt.close("all")
    CHECKS[path.name](printed.getvalue())
