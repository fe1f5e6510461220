"""The documentation site builds with no warning (`mkdocs build --strict`: every page in the
nav, every link and anchor found, every API page rendered from the docstrings), and the
README's links and commands point at what exists."""

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
README = (ROOT / "README.md").read_text()
TOOLS = ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python")


def _missing_tools() -> list[str]:
    missing = []
    for name in TOOLS:
        try:
            found = importlib.util.find_spec(name) is not None
        except ModuleNotFoundError:  # a parent package missing
            found = False
        if not found:
            missing.append(name)
    return missing


@pytest.mark.skipif(
    bool(_missing_tools()),
    reason=f"the docs tools are not installed ({', '.join(_missing_tools())}): "
    "pip install -e '.[test]'",
)
def test_site_builds_strict(tmp_path):
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # Material's notice on every build
    config = str(ROOT / "mkdocs.yml")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", config, "-d", str(site)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    # The API pages list each package's re-exported names (`from ._x import y as y`), which
    # mkdocstrings leaves out unless docs/_griffe/redundant_alias.py marks them public.
    api = (site / "api" / "ctjax" / "index.html").read_text()
    for name in ("ctjax.render", "ctjax.Estimate", "ctjax.cook_torrance_brdf"):
        assert f'id="{name}"' in api, name
    lobes = (site / "api" / "lobes" / "index.html").read_text()
    assert 'id="ctjax.lobes.AbstractLobe"' in lobes


def test_readme_links_exist():
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", README)
    relative = [link for link in links if "://" not in link]
    assert relative, "the README links to the docs pages"
    for link in relative:
        assert (ROOT / link).exists(), link


def test_readme_test_command_is_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    commands = re.findall(r"```bash\n(.*?)\n```", README, re.S)
    assert ci in commands, ci
    assert any(c.endswith(".venv/bin/ctjax demo --out ctjax-demo") for c in commands)
