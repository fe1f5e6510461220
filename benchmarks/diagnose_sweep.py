"""Does `ctjax diagnose` name the hidden effect? One synthetic capture per effect, textured.

    .venv/bin/python benchmarks/diagnose_sweep.py [--size 160x128] [--frames 6] [--seed 11]
                                                  [--texture-contrast 1.0] [--no-texture]

For nothing hidden and for each effect `ctjax synth` can hide (at the strengths below, the
ones `tests/test_diagnostics.py` uses), synthesises a capture and diagnoses it as the
command does (the albedo chosen as the command chooses it: on textured captures the map).
Prints per capture the verdict, the base model's held-out RMSE, the noise floor, the best
candidate's held-out RMSE and its improvement, and the seconds; one JSON line each. With
the light at the camera, Schlick's factor is exactly 1: `fresnel_schlick` is hidden with a
light offset, which the diagnosis names first.
"""

import argparse
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from _results import emit  # noqa: E402

import ctjax  # noqa: E402
from ctjax.diagnostics import diagnose  # noqa: E402
from ctjax.io import load_capture  # noqa: E402
from ctjax.synth import SynthOptions, synthesize  # noqa: E402

HIDDEN = {
    "none": ({}, None),
    "light_offset": ({"light_offset": (0.0, -6.0, 0.0)}, None),
    "inverse_square": ({"inverse_square": True}, None),
    "spot_falloff": ({"spot_falloff": 3.0}, None),
    "camera_gamma": ({"camera_gamma": 1.8}, None),
    "ambient": ({"ambient": (0.03, 0.02, 0.02)}, None),
    "ggx": ({"ggx": True}, None),
    "second_lobe": ({"second_lobe": (0.55, 0.6)}, None),
    "geometric_attenuation": ({"geometric_attenuation": True}, 0.6),  # rough: G acts
    "fresnel_schlick": ({"fresnel_schlick": 0.05, "light_offset": (0.0, -6.0, 0.0)}, None),
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="160x128")
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--texture-contrast", type=float, default=1.0)
    parser.add_argument("--no-texture", action="store_true")
    args = parser.parse_args()
    ctjax.tune_malloc()
    width, height = map(int, args.size.split("x"))
    with tempfile.TemporaryDirectory() as folder:
        for name, (effects, sigma) in HIDDEN.items():
            options = SynthOptions(
                width=width,
                height=height,
                frames=args.frames,
                seed=args.seed,
                texture=not args.no_texture,
                texture_contrast=args.texture_contrast,
                effects=effects,
                **({} if sigma is None else {"sigma": sigma}),
            )
            capture = load_capture(synthesize(Path(folder) / name, options))
            started = time.perf_counter()
            diagnosis = diagnose(capture)
            seconds = time.perf_counter() - started
            best = diagnosis.candidates[0]
            row = {
                "hidden": name,
                "size": args.size,
                "frames": args.frames,
                "seed": args.seed,
                "texture": 0.0 if args.no_texture else args.texture_contrast,
                "verdict": diagnosis.verdict,
                "albedo": diagnosis.base.details.get("albedo"),
                "base_rmse": round(diagnosis.base_rmse, 3),
                "noise_floor": round(diagnosis.noise_floor, 3),
                "best": best.details["effect"],
                "best_rmse": round(best.heldout_rmse, 3),
                "improvement": round(best.details["improvement"], 4),
                "seconds": round(seconds, 1),
            }
            print(
                f"{name:22s} verdict {row['verdict']:22s} base {row['base_rmse']:5.2f} "
                f"floor {row['noise_floor']:5.2f}  best {row['best']} {row['best_rmse']:.2f} "
                f"({100 * row['improvement']:+.1f}%)  {row['seconds']:.0f} s"
            )
            emit(row)


if __name__ == "__main__":
    main()
