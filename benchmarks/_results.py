"""One results file per benchmark run, so that figures can be compared between commits.

`emit(row)` prints a row as one JSON line (as every benchmark does) and appends it, with
the commit, the script, the machine and the time of the run, to
`benchmarks/results/SCRIPT-YYYYmmddTHHMMSS-COMMIT.jsonl` (folder: `$CTJAX_RESULTS_DIR`;
`CTJAX_RESULTS_DIR=""` writes none). The folder is not versioned: compare runs with, e.g.,
`cat benchmarks/results/render-*.jsonl | jq -c '{commit, seconds_median}'`.
"""

import datetime
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

_ROOT = Path(__file__).resolve().parent


def _commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=_ROOT,
            capture_output=True,
            text=True,
            timeout=10,
        )
        commit = out.stdout.strip() or "unknown"
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=_ROOT,
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
        return commit + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


_SCRIPT = Path(sys.argv[0]).stem or "python"
_STARTED = datetime.datetime.now(datetime.UTC)
_CONTEXT = {
    "commit": _commit(),
    "script": _SCRIPT,
    "run": _STARTED.isoformat(timespec="seconds"),
    "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.node()}",
}


def results_file() -> Path | None:
    """This run's file (None when `CTJAX_RESULTS_DIR` is set to "")."""
    folder = os.environ.get("CTJAX_RESULTS_DIR", str(_ROOT / "results"))
    if not folder:
        return None
    stamp = _STARTED.strftime("%Y%m%dT%H%M%S")
    return Path(folder) / f"{_SCRIPT}-{stamp}-{_CONTEXT['commit']}.jsonl"


def emit(row: dict) -> None:
    """Print `row` as a JSON line and append it, with the run's context, to this run's
    results file."""
    print(json.dumps(row), flush=True)
    path = results_file()
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as out:
        out.write(json.dumps({**_CONTEXT, **row}) + "\n")
