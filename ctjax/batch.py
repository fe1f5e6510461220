"""`ctjax batch`: many captures at once, on Dask (`dask.distributed`).

Each capture runs the chosen steps, the same commands as one at a time (`ctjax fit`,
`ctjax calibrate-light`, `ctjax diagnose`, `ctjax evaluate`; `reconstruct` first for a
capture with images only), in a worker process, and writes their JSON into `OUT/NAME/`
(`fit.json`, `calibrate-light.json`, ...), then `OUT/NAME/done.json`. `OUT/summary.csv`
and `OUT/summary.html` have one row per capture: `capture`, `status` (ok or failed), the
error's one line, the seconds, and the figures of its JSON files (sigma, F_tilde,
rho_tilde, the held-out RMSE and noise floor of the light, the light offset, the verdict).

- Workers: a local cluster of `workers` processes (one thread each: JAX uses the cores),
  or an existing scheduler (`scheduler="tcp://host:8786"`, e.g. one started by
  dask-jobqueue on a SLURM cluster); `workers=0` runs every capture in this process,
  without Dask.
- A capture that fails is reported (its row says why) and the others go on.
- Rerunning skips the captures whose `done.json` is there: delete it, or the folder, to
  run one again.
- `effects`: image effects (`--effects`, by name) given to the steps that take them:
  `fit` (frame_exposure only), `calibrate-light` and `evaluate`.
"""

import contextlib
import csv
import dataclasses
import html
import io
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ._commands import COMMANDS
from ._commands._runner import execute, parser_of
from ._errors import CtjaxError
from .io._atomic import atomic_write_bytes, atomic_write_json

STEPS = ("reconstruct", "fit", "calibrate-light", "diagnose", "evaluate")
# The steps that fit image effects (`--effects`), and those `fit` takes.
EFFECT_STEPS = ("fit", "calibrate-light", "evaluate")
FIT_EFFECTS = ("frame_exposure",)
DEFAULT_STEPS = ("fit", "calibrate-light", "diagnose")
COLUMNS = (
    "capture",
    "status",
    "error",
    "seconds",
    "length_unit",
    "sigma",
    "F_tilde",
    "rho_tilde",
    "albedo",
    "fit_status",
    "fit_exposure",
    "light_status",
    "light_heldout_rmse",
    "light_noise_floor",
    "offset",
    "verdict",
)


@dataclasses.dataclass(frozen=True)
class CaptureJob:
    """One capture's work: its folder, the steps, and where the results go."""

    capture: Path
    out: Path
    steps: tuple[str, ...]
    effects: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return self.capture.name

    @property
    def folder(self) -> Path:
        return self.out / self.name


def _step_argv(step: str, capture: Path, folder: Path, effects: tuple[str, ...] = ()) -> list[str]:
    json_path = str(folder / f"{step}.json")
    if step == "reconstruct":
        return [step, str(capture), "--out", str(folder / "capture"), "--json", json_path]
    extra = ["--effects", *effects] if effects and step in EFFECT_STEPS else []
    return [step, str(capture), "--json", json_path, *extra]


def _run_step(argv: list[str]) -> int:
    """`ctjax STEP ...` in this process, as the command line runs it: the same commands'
    parser (`ctjax`'s but `batch`), set-up and one-line errors on stderr, which the row
    quotes. From `ctjax._commands`, not `ctjax.cli`, which imports this module for `ctjax
    batch`: the dependency goes one way."""
    return execute(parser_of(COMMANDS.values()), argv)


def run_job(job: CaptureJob) -> dict:
    """Run `job`'s steps (in this process) and return its summary row. Never raises: a
    failure is the row's `status` and `error`."""
    started = time.perf_counter()
    job.folder.mkdir(parents=True, exist_ok=True)
    capture = job.capture
    error = ""
    for step in job.steps:
        stderr = io.StringIO()
        try:
            with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
                status = _run_step(_step_argv(step, capture, job.folder, job.effects))
        except Exception as failure:  # one capture must not stop the batch
            status, error = 1, f"{step}: {type(failure).__name__}: {failure}".splitlines()[0]
        if status != 0:
            lines = [line for line in stderr.getvalue().splitlines() if "error" in line]
            error = error or (lines[-1] if lines else f"{step} exited with status {status}")
            break
        if step == "reconstruct":
            capture = job.folder / "capture"
    row = {"capture": job.name, "status": "failed" if error else "ok", "error": error}
    row["seconds"] = round(time.perf_counter() - started, 1)
    row.update(figures(job.folder))
    if not error:
        atomic_write_json(job.folder / "done.json", row)
    return row


def figures(folder: Path) -> dict:
    """The summary's figures from the JSON files in a capture's result folder."""
    read = {}
    for step in STEPS:
        path = folder / f"{step}.json"
        if path.is_file():
            read[step] = json.loads(path.read_text())
    fit = read.get("fit", {})
    light = read.get("calibrate-light", {})
    offset = light.get("offset_mm", light.get("offset"))
    return {
        "length_unit": fit.get("length_unit", light.get("length_unit", "")),
        "sigma": fit.get("sigma", ""),
        "F_tilde": _triple(fit.get("F_tilde")),
        "rho_tilde": _triple(fit.get("rho_tilde")),
        "albedo": fit.get("albedo", ""),
        # Not "successful" where the data do not determine the lobe (`ctjax._determined`).
        "fit_status": fit.get("status", ""),
        # "per_frame" where the fit took a gain per frame (the frames' brightness moved its
        # lobe: a scope's auto-exposure), "one" else (`ctjax.estimation.fit_capture`).
        "fit_exposure": (fit.get("exposure") or {}).get("fitted", ""),
        "light_status": light.get("status", ""),
        "light_heldout_rmse": light.get("rgb_rmse_heldout", ""),
        "light_noise_floor": light.get("noise_floor", ""),
        "offset": _triple(offset),
        "verdict": read.get("diagnose", {}).get("verdict", ""),
    }


def _triple(values) -> str:
    return "" if values is None else " ".join(f"{v:.4g}" for v in values)


def _require_dask() -> None:
    """One `CtjaxError` naming the install when dask.distributed is missing."""
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        raise CtjaxError(
            "ctjax batch needs dask.distributed: pip install 'ctjax[batch]' (or --workers 0 "
            "to run the captures one after the other, without Dask)"
        ) from None


def _client(workers: int, scheduler: str | None):
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            return Client(scheduler, timeout=30)
        except (OSError, ValueError, TypeError) as failure:  # unreachable, or not an address
            raise CtjaxError(f"cannot reach the Dask scheduler at {scheduler}: {failure}") from None
    cluster = LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
    )
    return Client(cluster)


def run_batch(
    captures: Sequence[str | Path],
    out: str | Path,
    steps: Sequence[str] = DEFAULT_STEPS,
    *,
    workers: int = 2,
    scheduler: str | None = None,
    progress: Callable[[str], None] = lambda message: None,
    effects: Sequence[str] = (),
) -> list[dict]:
    """Run `steps` on every capture (see the module doc); returns the summary rows, in the
    order of `captures`, and writes `out/summary.csv` and `out/summary.html`."""
    jobs, rows = _jobs(captures, Path(out), tuple(steps), tuple(effects)), {}
    if workers != 0 or scheduler is not None:
        _require_dask()  # before any work, not when the first capture is submitted
    todo = [job for job in jobs if not (job.folder / "done.json").is_file()]
    for job in jobs:
        if job not in todo:
            rows[job.name] = json.loads((job.folder / "done.json").read_text())
    if len(todo) < len(jobs):
        progress(f"{len(jobs) - len(todo)} capture(s) already done (skipped)")
    for row in _run(todo, workers, scheduler, progress):
        rows[row["capture"]] = row
    ordered = [rows[job.name] for job in jobs]
    write_summary(Path(out), ordered)
    return ordered


def _jobs(captures, out: Path, steps, effects=()) -> list[CaptureJob]:
    _check_effects(steps, effects)
    unknown = [s for s in steps if s not in STEPS]
    if unknown:
        raise CtjaxError(f"unknown step(s) {', '.join(unknown)}; the steps are {', '.join(STEPS)}")
    if not steps:
        raise CtjaxError(f"no step given; the steps are {', '.join(STEPS)}")
    if not captures:
        raise CtjaxError("no capture given")
    missing = [str(c) for c in captures if not Path(c).is_dir()]
    if missing:  # before any work, not as a failed row after the others ran
        raise CtjaxError(f"not a capture folder: {', '.join(missing)}")
    # Absolute, not resolved: a capture given as a link keeps the link's name (two
    # reconstructions both named `reconstructed`, linked under their sequences' names).
    jobs = [CaptureJob(Path(c).absolute(), out.resolve(), steps, effects) for c in captures]
    names = [job.name for job in jobs]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise CtjaxError(
            f"captures with the same folder name ({', '.join(repeated)}) would share a result "
            "folder: rename them, or give them as links of distinct names"
        )
    return jobs


def _check_effects(steps, effects) -> None:
    """The effects' names, before any work (not as the same failure in every row)."""
    from .effects import image_effect_names

    names = image_effect_names()
    unknown = [e for e in effects if e not in names]
    if unknown:
        raise CtjaxError(
            f"effects {', '.join(unknown)}: not image effects; they are {', '.join(names)}"
        )
    if "fit" in steps and any(e not in FIT_EFFECTS for e in effects):
        raise CtjaxError(
            f"--effects {' '.join(effects)} with the fit step: fit takes {', '.join(FIT_EFFECTS)} "
            "only (calibrate-light and evaluate take every image effect)"
        )
    if effects and not any(s in EFFECT_STEPS for s in steps):
        raise CtjaxError(f"--effects is for the steps {', '.join(EFFECT_STEPS)}")


def _run(jobs: list[CaptureJob], workers: int, scheduler: str | None, progress):
    if not jobs:
        return
    if workers == 0 and scheduler is None:
        for done, job in enumerate(jobs, 1):
            row = run_job(job)
            progress(_line(done, len(jobs), row))
            yield row
        return
    from dask.distributed import as_completed

    with _client(workers, scheduler) as client:
        futures = [client.submit(run_job, job, key=f"ctjax-{job.name}", pure=False) for job in jobs]
        progress(f"{len(jobs)} capture(s) on {len(client.scheduler_info()['workers'])} worker(s)")
        for done, future in enumerate(as_completed(futures), 1):
            row = future.result()
            progress(_line(done, len(jobs), row))
            yield row


def _line(done: int, total: int, row: dict) -> str:
    what = row["status"] + (f": {row['error']}" if row["error"] else "")
    return f"[{done}/{total}] {row['capture']} {what} ({row['seconds']} s)"


def write_summary(out: Path, rows: list[dict]) -> None:
    """`out/summary.csv` and `out/summary.html`, one row per capture."""
    out.mkdir(parents=True, exist_ok=True)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(out / "summary.csv", buffer.getvalue().encode())
    head = "".join(f"<th>{html.escape(c)}</th>" for c in COLUMNS)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(row.get(c, '')))}</td>" for c in COLUMNS) + "</tr>"
        for row in rows
    )
    failed = sum(row["status"] != "ok" for row in rows)
    page = (
        '<!doctype html><html lang="en"><head><meta charset="utf-8"><title>ctjax batch</title>'
        "<style>body{font-family:sans-serif}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:3px 6px}</style></head><body>"
        f"<h1>ctjax batch: {len(rows)} capture(s), {failed} failed</h1>"
        f"<table><tr>{head}</tr>{body}</table></body></html>"
    )
    atomic_write_bytes(out / "summary.html", page.encode())
