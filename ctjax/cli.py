"""The `ctjax` command line: `ctjax synth`, `ctjax demo`.

Bad input is reported on one line naming the problem (and the file), exit status 2, no
traceback.
"""

import argparse
import sys
from pathlib import Path

from ._errors import CtjaxError


def _synth_options_from(args: argparse.Namespace):
    from .synth import SynthOptions

    return SynthOptions(
        width=args.width,
        height=args.height,
        frames=args.frames,
        seed=args.seed,
        texture=not args.no_texture,
        noise_levels=args.noise,
        bits=args.bits,
        rho_tilde=tuple(args.rho) if args.rho else SynthOptions.rho_tilde,
        F_tilde=tuple(args.F) if args.F else SynthOptions.F_tilde,
        sigma=args.sigma,
        light_offset_mm=tuple(args.light_offset) if args.light_offset else None,
        inverse_square=args.inverse_square,
        spot_exponent=args.spot,
        camera_gamma=args.gamma,
        ambient=_rgb(args.ambient),
        fresnel_f0=args.fresnel_schlick,
        geometric_attenuation=args.geometric_attenuation,
        ggx=args.ggx,
        second_lobe=tuple(args.second_lobe) if args.second_lobe else None,
    )


def _rgb(values):
    if values is None:
        return None
    if len(values) == 1:
        return (values[0],) * 3
    if len(values) != 3:
        raise CtjaxError(f"expected 1 or 3 values (R G B), got {len(values)}")
    return tuple(values)


def _add_synth_arguments(parser: argparse.ArgumentParser, *, frames: int, texture: bool) -> None:
    from .synth import SynthOptions

    size = parser.add_argument_group("capture")
    size.add_argument("--frames", type=int, default=frames, help="number of frames")
    size.add_argument("--seed", type=int, default=0, help="random seed (organ, path, noise)")
    size.add_argument("--width", type=int, default=SynthOptions.width)
    size.add_argument("--height", type=int, default=SynthOptions.height)
    if texture:
        size.add_argument("--no-texture", action="store_true", help="uniform albedo")
    else:
        size.set_defaults(no_texture=True)
    size.add_argument("--noise", type=float, default=1.0, help="Gaussian noise, 8-bit levels")
    size.add_argument("--bits", type=int, default=8, choices=(8, 16), help="PNG bit depth")
    model = parser.add_argument_group("reflectance (linear units, 1.0 = 8-bit level 255)")
    model.add_argument("--rho", type=float, nargs=3, metavar=("R", "G", "B"), help="rho_tilde")
    model.add_argument("--F", type=float, nargs=3, metavar=("R", "G", "B"), help="F_tilde")
    model.add_argument("--sigma", type=float, default=SynthOptions.sigma, help="roughness")
    effects = parser.add_argument_group("effects beyond the paper's model (all off by default)")
    effects.add_argument(
        "--light-offset",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="point light at this camera-frame offset from the lens, mm",
    )
    effects.add_argument(
        "--inverse-square", action="store_true", help="inverse-square falloff (1 at 70 mm)"
    )
    effects.add_argument("--spot", type=float, metavar="K", help="angular falloff cos^K")
    effects.add_argument("--gamma", type=float, help="camera response radiance^(1/gamma)")
    effects.add_argument(
        "--ambient", type=float, nargs="+", metavar="A", help="ambient radiance, one value or R G B"
    )
    effects.add_argument(
        "--fresnel-schlick", type=float, metavar="F0", help="Schlick Fresnel with this F0"
    )
    effects.add_argument(
        "--geometric-attenuation", action="store_true", help="Cook-Torrance geometric attenuation G"
    )
    effects.add_argument("--ggx", action="store_true", help="GGX instead of Beckmann")
    effects.add_argument(
        "--second-lobe",
        type=float,
        nargs=2,
        metavar=("SIGMA", "FRACTION"),
        help="a second Beckmann lobe with F_tilde * FRACTION",
    )


def _cmd_synth(args: argparse.Namespace) -> int:
    from .synth import synthesize

    out = synthesize(args.out, _synth_options_from(args))
    print(f"wrote synthetic capture to {out}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    summary = run_demo(Path(args.out), _synth_options_from(args))
    print(f"report: {Path(args.out) / 'report.html'}")
    print(f"summary: {Path(args.out) / 'summary.json'} (RGB RMSE {summary['rgb_rmse']:.2f} levels)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ctjax",
        description="Cook-Torrance reflectance and laparoscope light from images (JAX).",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    synth = commands.add_parser("synth", help="generate a synthetic laparoscope capture")
    synth.add_argument("out", type=Path, help="output capture folder")
    _add_synth_arguments(synth, frames=5, texture=True)
    synth.set_defaults(run=_cmd_synth)

    demo = commands.add_parser("demo", help="the main job on a built-in synthetic capture")
    demo.add_argument("--out", default="ctjax-demo", help="output folder (default: ctjax-demo)")
    _add_synth_arguments(demo, frames=5, texture=False)
    demo.set_defaults(run=_cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from ._performance import tune_malloc

    tune_malloc()
    try:
        return args.run(args)
    except CtjaxError as error:
        print(f"ctjax {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ctjax {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
