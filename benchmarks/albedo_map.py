"""The BRDF fit with an albedo map against the paper's uniform albedo, same run.

    python benchmarks/albedo_map.py [--sizes 320x256 640x512] [--frames 8] [--seed 1]
                                     [--repeats 5]

On per-channel textured synthetic captures with true depth and poses (1 level of noise,
8 bits), fits `fit_capture(albedo="map")` and `fit_capture(albedo="uniform")` (the first
call compiles; the next `--repeats` alternate map and uniform, and their medians are
reported), and prints the time ratio (of the medians, and per repeat: its median and
range; the fit, and the fit with every frame's dense albedo map read, which `fit_capture`
estimates at the first read), the errors of sigma and F_tilde against the truth, the albedo
maps' median and 90th percentile relative error and coverage, and the peak resident memory
of the process. One JSON line per size.
"""

import argparse
import resource
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from _results import emit  # noqa: E402

import ctjax  # noqa: E402
from ctjax import CtjaxError  # noqa: E402
from ctjax.estimation import fit_capture  # noqa: E402
from ctjax.io import load_capture  # noqa: E402
from ctjax.synth import SynthOptions, synthesize  # noqa: E402


def _first(capture, albedo):
    """The first call (it compiles), with every frame's map read; the fit's error message
    instead when it fails (the paper's 3 px ring can be empty at 640x512)."""
    try:
        estimate = fit_capture(capture, albedo=albedo)
        list(estimate.arrays.values())
        return estimate
    except CtjaxError as error:
        return str(error)


def _timed(capture, repeats):
    """Both fits timed in alternation, `repeats` times each after a first call: this
    machine's speed drifts by 10-20% within a minute, and alternating lets each ratio
    compare neighbouring calls. Returns the estimates and the per-repeat seconds of the map
    fit, of the map fit with every frame's map read too (they are estimated at the first
    read) and of the uniform fit (NaN for a fit that fails)."""
    estimates = {albedo: _first(capture, albedo) for albedo in ("map", "uniform")}
    times = {"map": [], "with_maps": [], "uniform": []}
    for _ in range(repeats):
        for albedo in ("map", "uniform"):
            if isinstance(estimates[albedo], str):
                times[albedo].append(float("nan"))
                continue
            started = time.perf_counter()
            estimate = fit_capture(capture, albedo=albedo)
            times[albedo].append(time.perf_counter() - started)
            if albedo == "map":
                list(estimate.arrays.values())
                times["with_maps"].append(time.perf_counter() - started)
    return estimates, {name: np.asarray(t) for name, t in times.items()}


def _map_errors(root, estimate):
    errors, coverage = [], []
    for path in sorted((root / "albedo").glob("*.npy")):
        truth = np.load(path)
        estimated = estimate.arrays[f"albedo/{path.stem}"]
        surface = np.all(np.isfinite(truth), -1)
        both = surface & np.all(np.isfinite(estimated), -1)
        coverage.append(both.sum() / surface.sum())
        errors.append(np.abs(estimated[both] / truth[both] - 1).ravel())
    errors = np.concatenate(errors)
    return float(np.median(errors)), float(np.percentile(errors, 90)), float(min(coverage))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["320x256", "640x512"])
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5, help="timed calls (median)")
    parser.add_argument("--no-malloc-tuning", action="store_true")
    args = parser.parse_args()
    if not args.no_malloc_tuning:
        ctjax.tune_malloc()  # as `ctjax fit` does
    for size in args.sizes:
        width, height = map(int, size.split("x"))
        with tempfile.TemporaryDirectory() as folder:
            root = synthesize(
                Path(folder) / "c",
                SynthOptions(width=width, height=height, frames=args.frames, seed=args.seed),
            )
            capture = load_capture(root)
            truth = capture.truth
            estimates, times = _timed(capture, args.repeats)
            mapped, uniform = estimates["map"], estimates["uniform"]
            median, p90, coverage = _map_errors(root, mapped)
        map_s, uniform_s = float(np.median(times["map"])), float(np.median(times["uniform"]))
        with_maps_s = float(np.median(times["with_maps"]))
        ratios = times["map"] / times["uniform"]
        row = {"size": size, "frames": args.frames, "seed": args.seed, "repeats": args.repeats}
        for name, estimate, seconds in (("map", mapped, map_s), ("uniform", uniform, uniform_s)):
            if isinstance(estimate, str):
                row[f"{name}_error"] = estimate
                row[f"{name}_sigma_error"], row[f"{name}_F_error"] = float("nan"), []
                continue
            fit = estimate.to_json()
            row[f"{name}_s"] = round(seconds, 2)
            row[f"{name}_sigma_error"] = round(fit["sigma"] / truth["sigma"] - 1, 5)
            row[f"{name}_F_error"] = [
                round(f / t - 1, 5) for f, t in zip(fit["F_tilde"], truth["F_tilde"], strict=True)
            ]
        row["time_ratio"] = round(map_s / uniform_s, 2)
        # Each repeat's ratio of neighbouring calls: their median and range.
        row["time_ratio_paired_median"] = round(float(np.median(ratios)), 2)
        row["time_ratio_paired_range"] = [
            round(float(np.min(ratios)), 2),
            round(float(np.max(ratios)), 2),
        ]
        row["map_with_maps_s"] = round(with_maps_s, 2)
        row["time_ratio_with_maps"] = round(with_maps_s / uniform_s, 2)
        row["map_median_error"], row["map_p90_error"] = round(median, 5), round(p90, 5)
        row["map_min_coverage"] = round(coverage, 4)
        row["peak_rss_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
        print(
            f"{size} x{args.frames}: map {map_s:.2f} s vs uniform {uniform_s:.2f} s "
            f"(ratio {row['time_ratio']}; per repeat {row['time_ratio_paired_median']}, "
            f"{row['time_ratio_paired_range'][0]}-{row['time_ratio_paired_range'][1]}; "
            f"reading every frame's map too: {with_maps_s:.2f} s, "
            f"ratio {row['time_ratio_with_maps']}); sigma {row['map_sigma_error']:+.2%} (uniform "
            f"{row['uniform_sigma_error']:+.1%} {row.get('uniform_error', '')}), "
            f"F_tilde {row['map_F_error']} (uniform "
            f"{row['uniform_F_error']}); albedo maps: median {median:.2%}, p90 {p90:.2%}, "
            f"coverage {coverage:.1%}; peak RSS {row['peak_rss_mib']} MiB"
        )
        emit(row)


if __name__ == "__main__":
    main()
