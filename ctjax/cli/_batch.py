"""`ctjax batch`: its parser and its body, which hands the captures to `ctjax.batch`.

Here in the command line's top layer, not beside the other commands in `ctjax._commands`:
`ctjax.batch` runs those commands as its steps, so they are below it, and this one above.
"""

import argparse
import sys
from pathlib import Path

from .._commands._args import output_folder
from .._errors import CtjaxError


def add_batch_parser(commands) -> None:
    from ..batch import DEFAULT_STEPS, STEPS

    batch = commands.add_parser(
        "batch",
        help="many captures at once, on Dask",
        description="Runs the steps on every capture in parallel (dask.distributed: a local "
        "cluster of --workers processes, or an existing --scheduler); OUT/NAME/ gets the "
        "JSON files the single commands write, OUT/summary.csv and OUT/summary.html a row "
        "per capture. A failed capture is reported and the others go on; a rerun skips "
        "the captures already done (OUT/NAME/done.json).",
    )
    batch.add_argument("captures", type=Path, nargs="+", metavar="CAPTURE")
    batch.add_argument("--out", type=output_folder, required=True, help="results folder")
    batch.add_argument(
        "--steps",
        default=",".join(DEFAULT_STEPS),
        help=f"comma-separated, in order, from {', '.join(STEPS)}",
    )
    batch.add_argument(
        "--workers",
        type=int,
        default=2,
        help="local worker processes (0: one capture after the other, without Dask)",
    )
    batch.add_argument(
        "--scheduler", help="address of an existing Dask scheduler (e.g. tcp://host:8786)"
    )
    batch.add_argument(
        "--effects",
        nargs="+",
        default=[],
        metavar="EFFECT",
        help="image effects for the steps that fit them: fit (frame_exposure only), "
        "calibrate-light and evaluate (e.g. frame_exposure: a scope's auto-exposure)",
    )
    batch.set_defaults(run=run_batch)


def run_batch(args: argparse.Namespace) -> int:
    from .. import batch

    if args.workers < 0:
        raise CtjaxError(f"--workers must be 0 or more, got {args.workers}")
    steps = [s.strip() for s in args.steps.split(",") if s.strip()]
    rows = batch.run_batch(
        args.captures,
        args.out,
        steps,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=lambda m: print(f"[ctjax batch] {m}", flush=True),
        effects=tuple(args.effects),
    )
    failed = [row["capture"] for row in rows if row["status"] != "ok"]
    print(
        f"{len(rows) - len(failed)}/{len(rows)} capture(s) ok; wrote "
        f"{args.out / 'summary.csv'} and {args.out / 'summary.html'}"
    )
    if failed:
        print(f"ctjax batch: failed: {', '.join(failed)}", file=sys.stderr)
    return 0 if not failed else 1
