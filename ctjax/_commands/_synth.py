"""`ctjax synth` (a synthetic capture) and `ctjax demo` (the main job on one): the
synthetic capture's options, which both take.
"""

import argparse
from pathlib import Path

from ._args import add_falloff_argument, output_folder


def add_synth_parser(commands) -> None:
    synth = commands.add_parser("synth", help="generate a synthetic laparoscope capture")
    synth.add_argument("out", type=output_folder, help="output capture folder")
    _add_synth_arguments(synth, frames=5, texture=True)
    synth.add_argument(
        "--sparkles",
        action="store_true",
        help="highlights as sparkles: each pixel a facet tilted from the surface by a Beckmann "
        "slope of roughness --sigma, lit by a sharp lobe; truth.json's sigma is the effective "
        "roughness of both (what a pixel-averaged model sees)",
    )
    synth.add_argument(
        "--sparkles-attached",
        action="store_true",
        help="sparkles whose facets belong to the tissue (the same facet at a surface point in "
        "every frame, as on real wet tissue) instead of drawn anew each frame; implies --sparkles",
    )
    synth.add_argument(
        "--sparkle-px",
        type=float,
        default=None,
        help="the facets' correlation length in pixels (default 1.5: a tracked point's pixels "
        "see different facets; 6: they share one)",
    )
    synth.set_defaults(run=run_synth)


def add_demo_parser(commands) -> None:
    demo = commands.add_parser("demo", help="the main job on a built-in synthetic capture")
    demo.add_argument(
        "--out",
        type=output_folder,
        default="ctjax-demo",
        help="output folder (default: ctjax-demo)",
    )
    # texture contrast: ctjax.demo.DEMO_TEXTURE_CONTRAST (not imported here: it loads JAX)
    _add_synth_arguments(demo, frames=5, texture=True, texture_contrast=0.3)
    add_falloff_argument(demo)
    demo.set_defaults(run=run_demo)


def _add_synth_arguments(
    parser: argparse.ArgumentParser, *, frames: int, texture: bool, texture_contrast: float = 1.0
) -> None:
    from ..synth import SynthOptions, synth_effects

    size = parser.add_argument_group("capture")
    size.add_argument("--frames", type=int, default=frames, help="number of frames")
    size.add_argument("--seed", type=int, default=0, help="random seed (organ, path, noise)")
    size.add_argument("--width", type=int, default=SynthOptions.width)
    size.add_argument("--height", type=int, default=SynthOptions.height)
    size.add_argument(
        "--stereo",
        type=float,
        metavar="BASELINE_MM",
        help="a stereo laparoscope: right images from a camera this far right (mm)",
    )
    if texture:
        size.add_argument("--no-texture", action="store_true", help="uniform albedo")
    else:
        size.set_defaults(no_texture=True)
    size.add_argument(
        "--texture-contrast",
        type=float,
        default=texture_contrast,
        help="scale of the albedo texture's contrast, 0-1 (default %(default)s)",
    )
    size.add_argument("--noise", type=float, default=1.0, help="Gaussian noise, 8-bit levels")
    size.add_argument("--bits", type=int, default=8, choices=(8, 16), help="PNG bit depth")
    model = parser.add_argument_group("reflectance (linear units, 1.0 = 8-bit level 255)")
    model.add_argument("--rho", type=float, nargs=3, metavar=("R", "G", "B"), help="rho_tilde")
    model.add_argument("--F", type=float, nargs=3, metavar=("R", "G", "B"), help="F_tilde")
    model.add_argument("--sigma", type=float, default=SynthOptions.sigma, help="roughness")
    effects = parser.add_argument_group("effects beyond the paper's model (all off by default)")
    # Each effect declares its own options, beside its physics (its candidate).
    for effect in synth_effects().values():
        effect.add_synth_arguments(effects)


def _synth_options_from(args: argparse.Namespace):
    from ..synth import SynthOptions, synth_effects

    effects = {}
    for name, effect in synth_effects().items():
        value = effect.synth_value(args)
        if value is not None:
            effects[name] = value
    return SynthOptions(
        width=args.width,
        height=args.height,
        frames=args.frames,
        seed=args.seed,
        texture=not args.no_texture,
        texture_contrast=args.texture_contrast,
        noise_levels=args.noise,
        bits=args.bits,
        rho_tilde=tuple(args.rho) if args.rho else SynthOptions.rho_tilde,
        F_tilde=tuple(args.F) if args.F else SynthOptions.F_tilde,
        sigma=args.sigma,
        effects=effects,
        stereo_mm=getattr(args, "stereo", None),
        sparkles=getattr(args, "sparkles", False),
        sparkles_attached=getattr(args, "sparkles_attached", False),
        **({} if getattr(args, "sparkle_px", None) is None else {"sparkle_px": args.sparkle_px}),
    )


def run_synth(args: argparse.Namespace) -> int:
    from ..synth import synthesize

    out = synthesize(args.out, _synth_options_from(args))
    print(f"wrote synthetic capture to {out}")
    return 0


def run_demo(args: argparse.Namespace) -> int:
    from .. import demo

    summary = demo.run_demo(Path(args.out), _synth_options_from(args), falloff=args.falloff)
    evaluation = summary["evaluation"]
    print(f"report: {Path(args.out) / 'report.html'}")
    print(
        f"summary: {Path(args.out) / 'summary.json'} (test-frame RGB RMSE: Cook-Torrance "
        f"{evaluation['cook_torrance_rgb_rmse_test']:.2f}, Lambertian "
        f"{evaluation['lambertian_rgb_rmse_test']:.2f} levels)"
    )
    return 0
