"""The two tiers of tests (tests/conftest.py): the slow one is left out of the README's test
command, run with `--slow` or asked for by `-m`, and a slow test named on the command line
runs whatever its tier."""

import types

import conftest
import pytest


class _Item:
    def __init__(self, nodeid: str, slow: bool):
        self.nodeid, self.slow = nodeid, slow

    def get_closest_marker(self, name):
        return object() if self.slow and name == "slow" else None


def _config(args=("tests",), slow=False, markexpr=""):
    deselected = []
    config = types.SimpleNamespace(
        args=list(args),
        option=types.SimpleNamespace(markexpr=markexpr),
        getoption=lambda name: {"--slow": slow}[name],
        hook=types.SimpleNamespace(pytest_deselected=lambda items: deselected.extend(items)),
    )
    return config, deselected


ITEMS = [("tests/test_a.py::test_quick", False), ("tests/test_a.py::test_measured", True)]


@pytest.mark.parametrize(
    ("options", "kept"),
    [
        ({}, ["tests/test_a.py::test_quick"]),
        ({"slow": True}, ["tests/test_a.py::test_quick", "tests/test_a.py::test_measured"]),
        ({"markexpr": "slow"}, ["tests/test_a.py::test_quick", "tests/test_a.py::test_measured"]),
        (
            {"args": ["tests/test_a.py::test_measured"]},
            ["tests/test_a.py::test_quick", "tests/test_a.py::test_measured"],
        ),
    ],
)
def test_the_slow_tier_runs_only_when_asked_for(options, kept):
    items = [_Item(nodeid, slow) for nodeid, slow in ITEMS]
    config, deselected = _config(**options)
    conftest.pytest_collection_modifyitems(config, items)
    assert [item.nodeid for item in items] == kept
    assert [item.nodeid for item in deselected] == [
        nodeid for nodeid, _ in ITEMS if nodeid not in kept
    ]
