"""Fit the BRDF on patch-averaged images: does averaging a k x k patch of sparkles (each
pixel one facet) give back the Beckmann lobe of the patch (the effective sigma)?

The sets S and S~ come from the original frames; only the images the fit reads are
replaced by their k x k box (or Gaussian) average in linear intensity (`Frame.image` is
decoded already), over the pixels with geometry. Clipped pixels: `keep` averages them at
1.0 (they lose energy), `exclude` marks every patch holding one as clipped (the fit then
drops it, as it drops clipped pixels).

    python benchmarks/patch_average.py CAPTURE [CAPTURE ...] --k 1 5 9 15 --clipped keep exclude
"""

import argparse
import dataclasses
import json
import sys
import time


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("captures", nargs="+")
    parser.add_argument("--k", type=int, nargs="+", default=[1, 5, 9, 15])
    parser.add_argument("--clipped", nargs="+", default=["keep", "exclude"])
    parser.add_argument("--kernel", choices=("box", "gaussian"), default="box")
    parser.add_argument("--albedo", choices=("map", "uniform"), default=None)
    parser.add_argument("--json", help="append one JSON line per fit here")
    parser.add_argument(
        "--sets-from",
        help="take S and S~ from this capture (same frames, e.g. the same synth seed at a "
        "higher exposure, where the sparkles are found; S is empty without clipping)",
    )
    args = parser.parse_args()

    from ctjax.estimation._capture_fit import fit_capture
    from ctjax.estimation._patches import patch_averaged
    from ctjax.io import load_capture
    from ctjax.observations import Observations
    from ctjax.specular import MaskOptions

    masks = MaskOptions()
    for path in args.captures:
        capture = load_capture(path)
        truth = capture.truth or {}
        source = capture if args.sets_from is None else load_capture(args.sets_from)
        if source is not capture:
            # The field of view too: a dark (low-exposure) frame reads as endoscope border.
            frames = zip(capture.frames, source.frames, strict=True)
            capture = dataclasses.replace(
                capture,
                frames=tuple(
                    dataclasses.replace(f, field_of_view=s.field_of_view) for f, s in frames
                ),
            )
        sets = Observations.of(source, masks).sets
        for k in args.k:
            for clipped in args.clipped if k > 1 else ["keep"]:
                start = time.perf_counter()
                averaged = patch_averaged(capture, k, clipped=clipped, kernel=args.kernel)
                obs = Observations(averaged, masks)
                obs.sets = sets  # S and S~ of the original frames
                try:
                    result = fit_capture(obs, masks, albedo=args.albedo).to_json()
                except Exception as error:
                    result = {"status": f"error: {error}"}
                halves = result.get("halves") or {}
                row = {
                    "capture": path,
                    "k": k,
                    "kernel": args.kernel,
                    "clipped": clipped,
                    "sigma": result.get("sigma"),
                    "F_tilde": result.get("F_tilde"),
                    "status": result.get("status"),
                    "halves": [
                        halves.get(h, {}).get("sigma") for h in ("even_frames", "odd_frames")
                    ]
                    if halves
                    else None,
                    "truth_sigma": truth.get("sigma"),
                    "truth_F": truth.get("F_tilde"),
                    "seconds": round(time.perf_counter() - start, 1),
                }
                print(json.dumps(row), flush=True)
                if args.json:
                    with open(args.json, "a") as out:
                        out.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
