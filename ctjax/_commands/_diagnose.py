"""`ctjax diagnose`: where the model fails and which physical effect is missing, once or
in a loop that adds each verdict.
"""

import argparse
import sys
from pathlib import Path

from .._units import in_length_unit
from ._args import add_workers_argument, load_capture, output_file, output_folder, positive_int


def add_diagnose_parser(commands) -> None:
    diag = commands.add_parser(
        "diagnose", help="where the model fails, and which physical effect is missing"
    )
    diag.add_argument("capture", type=Path, help="capture folder (with depth)")
    diag.add_argument("--json", type=output_file, required=True, help="output JSON file")
    diag.add_argument(
        "--plots", type=output_folder, help="folder for residual maps and binned residuals"
    )
    diag.add_argument(
        "--add",
        nargs="+",
        default=[],
        metavar="EFFECT",
        help="effects to add to the base model first (e.g. light_offset)",
    )
    diag.add_argument("--calib", type=int, help="number of calibration frames (default 60%%)")
    diag.add_argument(
        "--max-samples",
        type=positive_int,
        default=12_000,
        metavar="N",
        help="calibration pixels (or tracked points, with the albedo map) each model is fitted "
        "on, a random subset (default %(default)s, at least 500; fewer run faster)",
    )
    diag.add_argument(
        "--albedo",
        choices=("map", "uniform"),
        help="one albedo per surface point (map; the default when every frame has depth and a "
        "pose) or one for the capture (uniform, the paper's; then the albedo_texture "
        "candidate tries the map)",
    )
    diag.add_argument(
        "--loop",
        action="store_true",
        help="add the verdict to the base model and diagnose again, until the verdict is "
        "none (or --max-rounds steps); prints the held-out RMSE step by step",
    )
    diag.add_argument(
        "--max-rounds",
        type=positive_int,
        default=5,
        metavar="N",
        help="--loop: at most this many diagnoses (default %(default)s)",
    )
    add_workers_argument(diag, "candidates")
    diag.set_defaults(run=run_diagnose)


def run_diagnose(args: argparse.Namespace) -> int:
    from ..diagnostics import (
        diagnose,
        diagnose_loop,
        diagnosis_plots,
        heldout_budget,
        plot_loop,
    )
    from ..io._atomic import atomic_write_json
    from ..observations import Observations
    from ..specular import highlight_alignment_line, highlight_alignment_summary

    capture = load_capture(args)
    # Decoded once: the diagnoses (every step of a loop) and the plots share them.
    observations = Observations.of(capture)
    options = dict(
        calibration=args.calib,
        add=tuple(args.add),
        albedo=args.albedo,
        max_samples=args.max_samples,
        workers=args.workers,
        progress=lambda m: print(f"[ctjax diagnose] {m}", flush=True),
    )
    loop = None
    if args.loop:
        loop = diagnose_loop(observations, max_rounds=args.max_rounds, **options)
        diagnosis = loop.final
    else:
        diagnosis = diagnose(observations, **options)
    summary = diagnosis.to_json()
    if loop is not None:
        summary["loop"] = loop.to_json()
        # The first step's (it chose the albedo): the later ones keep its choice.
        summary["warnings"] = list(loop.steps[0].warnings)
    # What is left of the last model's held-out residual, where no candidate took it.
    final = diagnosis.best_model if diagnosis.verdict != "none" else diagnosis.base.model
    budget = None
    try:
        if diagnosis.heldout is not None:
            budget = heldout_budget(diagnosis.heldout, final)
    except ValueError as error:
        summary["residual_budget"] = {"note": str(error)}
    if budget is not None:
        summary["residual_budget"] = budget.to_json()
    # Whether the shape places the highlights, where most of a real sequence's residual is.
    summary["highlight_alignment"] = highlight_alignment_summary(
        observations.capture, observations.sets
    )
    atomic_write_json(args.json, in_length_unit(summary, capture.length_unit))
    if args.plots:
        for path in diagnosis_plots(observations, diagnosis, args.plots):
            print(f"wrote {path}")
        if loop is not None:
            print(f"wrote {plot_loop(loop, Path(args.plots) / 'loop.png')}")
    if loop is not None:
        for k, step in enumerate(loop.steps):
            print(
                f"step {k + 1} ({' + '.join(['paper', *loop.added[:k]])}): held-out RMSE "
                f"{step.base_rmse:.2f} levels, {step.base_rmse / step.noise_floor:.2f}x the "
                f"noise floor {step.noise_floor:.2f}; verdict {step.verdict}"
                f"{'' if step.verdict_status is None else f', {step.verdict_status}'} "
                f"({step.seconds:.0f} s)"
            )
        print(f"loop stopped: {loop.stopped}; {loop.seconds:.0f} s in all")
    for warning in summary["warnings"]:
        print(f"ctjax diagnose: warning: {warning}", file=sys.stderr)
    if budget is not None:
        print(f"what is left: {budget.summary()}")
        if (note := facets_note(diagnosis.verdict, budget.highlight_share)) is not None:
            print(f"ctjax diagnose: note: {note}", file=sys.stderr)
    print(highlight_alignment_line(summary["highlight_alignment"]))
    for line in diagnosis.comparison():
        print(line)
    status = diagnosis.verdict_status
    print(
        f"verdict: {diagnosis.verdict}{'' if status is None else f', {status}'} "
        f"(base held-out RMSE {diagnosis.base_rmse:.2f} levels, "
        f"noise floor {diagnosis.noise_floor:.2f}); wrote {args.json} "
        f"in {diagnosis.seconds:.0f} s"
    )
    return 0


def facets_note(verdict: str, highlight_share: float) -> str | None:
    """Where the loop ends with no candidate and most of what is left lies near the
    highlights: the effect none of the candidates is, a lobe about finer facets (on real
    da Vinci and sinus frames, docs: real endoscopic video), and where ctjax judges it."""
    if verdict != "none" or highlight_share < 0.5:
        return None
    return (
        f"{100 * highlight_share:.0f}% of what is left lies within 7 px of the highlights "
        "and no candidate takes it: a lobe about each tracked point's own facet, its normal "
        "read from the views where it shone, may (`ctjax evaluate CAPTURE --facets` judges "
        "it on held-out frames)"
    )
