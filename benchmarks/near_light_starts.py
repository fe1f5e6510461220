"""Where the near light's fit spends its LM runs: every start's cost, steps and time.

    python benchmarks/near_light_starts.py CAPTURE [-- CALIBRATE-LIGHT OPTIONS]

Runs `ctjax calibrate-light CAPTURE --model near` (the options after `--` passed on, e.g.
`--effects frame_exposure`) with `fit_model_map` and its LM recorded: for each of the
near light's map fits, how many starts it was given, which parameters it held or froze,
and each LM start's final cost, steps and seconds (on its thread: the falloff sets run on
`--workers` threads at once). Then, over the fits that ran LM from two starts (`refine=2`):
how often the second start won and by how much, and how many pairs were the same start
twice. One JSON line per fit, then the summary.

Measured (2026-12-06, 4712fa4, the default options): the second sinus video's turbinate A
(24 frames, 640 px, `benchmarks/real_video.py`'s capture): 23 fits, 17 with two LM starts,
the second won 4 times, by 2.6% of the cost once (an offset fit with nothing frozen), under
5e-4 otherwise; 5 pairs were the same start twice (64 of 431 LM thread-seconds: the paper's
start's sigma 0.2 is one of `ROUGHNESS_STARTS` too). SCARED 61-84
(`benchmarks/scared_capture.py`, 24 pairs): 19 fits, 16 with two starts, the second won 5
times (by 0.2%, 0.08%, 0.78%, twice under 1e-10); 3 pairs the same start twice (15 of 223
thread-seconds). Since c01fb91 a start equal to one already run is not run again
(`ctjax.fitting._fit.distinct`): the same JSON field for field, 35 LM runs instead of 40 on
the turbinate. docs/measurements.md, "The near light's LM starts".
"""

import argparse
import sys
import threading
import time

import jax
import numpy as np
from _results import emit


def _recorded(calibrate_light_argv: list[str]) -> list[dict]:
    """Run the command with every map fit's LM starts recorded (one dict per fit)."""
    import ctjax.calibration._near_light as near_light
    import ctjax.fitting._map_least_squares as map_fit
    from ctjax.cli import main

    here, fits = threading.local(), []
    least_squares, fit_model_map = map_fit._least_squares, near_light.fit_model_map

    def timed(start, *args):
        began = time.perf_counter()
        out = least_squares(start, *args)
        cost, steps = float(out[3]), int(out[5])  # waits for the result
        if getattr(here, "fit", None) is not None:
            here.fit["starts"].append(
                {"cost": cost, "steps": steps, "seconds": time.perf_counter() - began}
            )
        return out

    def recorded(starts, tracks, **options):
        here.fit = {
            "given": 1 if not isinstance(starts, list | tuple) else len(starts),
            "hold": list(options.get("hold", ())),
            "freeze": list(options.get("freeze", ())),
            "starts": [],
        }
        try:
            return fit_model_map(starts, tracks, **options)
        finally:
            fits.append(here.fit)
            here.fit = None

    map_fit._least_squares, near_light.fit_model_map = timed, recorded
    try:
        code = main(calibrate_light_argv)
    finally:
        map_fit._least_squares, near_light.fit_model_map = least_squares, fit_model_map
    if code != 0:
        sys.exit(f"ctjax calibrate-light failed (exit {code})")
    return fits


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture")
    parser.add_argument("--json", default="/dev/null", help="calibrate-light's own JSON")
    parser.add_argument("options", nargs=argparse.REMAINDER)
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    options = [o for o in args.options if o != "--"]
    argv = ["calibrate-light", args.capture, "--model", "near", "--json", args.json, *options]
    fits = _recorded(argv)
    for fit in fits:
        emit(fit)
    pairs = [f["starts"] for f in fits if len(f["starts"]) == 2]
    second = [(b["cost"] - a["cost"]) / a["cost"] for a, b in pairs]
    twice = sum(a["cost"] == b["cost"] and a["steps"] == b["steps"] for a, b in pairs)
    wins = sorted(-s for s in second if s < 0)
    runs = [s for f in fits for s in f["starts"]]
    summary = {
        "fits": len(fits),
        "two_starts": len(pairs),
        "second_won": len(wins),
        "second_won_by": wins,
        "same_start_twice": twice,
        "lm_runs": len(runs),
        "lm_thread_seconds": float(np.sum([s["seconds"] for s in runs])),
    }
    emit(summary)
    print(
        f"{len(fits)} map fits, {len(pairs)} with two LM starts: the second won "
        f"{len(wins)} times (by {', '.join(f'{w:.2e}' for w in wins) or '-'} of the cost), "
        f"{twice} pairs the same start twice; {len(runs)} LM runs, "
        f"{summary['lm_thread_seconds']:.0f} thread-seconds"
    )


if __name__ == "__main__":
    main()
