"""`ctjax calibrate-light`: the laparoscope's light from images, a near point light
(`--model near`) or the paper's per-pixel light field (`--model field`).
"""

import argparse
import sys
from pathlib import Path

from .._errors import CtjaxError
from .._units import in_length_unit, label
from ._args import (
    add_diffuse_argument,
    add_effects_argument,
    add_falloff_argument,
    add_workers_argument,
    chosen_effects,
    effects_line,
    field_solver,
    load_observations,
    output_file,
)


def add_calibrate_light_parser(commands) -> None:
    light = commands.add_parser("calibrate-light", help="the laparoscope's light from images")
    light.add_argument("capture", type=Path, help="capture folder (with depth)")
    light.add_argument(
        "--model",
        choices=("near", "field"),
        default="near",
        help="near: point light offset from the lens; field: the paper's per-pixel "
        "light directions (eq. 7-8)",
    )
    light.add_argument("--json", type=output_file, required=True, help="output JSON file")
    light.add_argument(
        "--npz",
        type=output_file,
        help="field: output NPZ with the (H, W, 3) light directions, theta, phi, status",
    )
    add_falloff_argument(light)
    light.add_argument(
        "--offset",
        choices=("lens-plane", "free"),
        default="lens-plane",
        help="near: fit the light's offset in the lens plane (default: a scope's light leaves "
        "the face of its tip, beside or around the lens) or along the optical axis too (free: "
        "the axis is what the images determine worst)",
    )
    light.add_argument(
        "--engine",
        choices=("optimistix", "closed-form"),
        default="optimistix",
        help="field: the per-pixel LM solver, optimistix's (the reference) or a batched 2x2 "
        "one written out (closed-form: several times faster)",
    )
    light.add_argument(
        "--albedo",
        choices=("map", "uniform"),
        help="one albedo per surface point (map; the default when every frame has depth and "
        "a pose) or one for the capture (uniform, the paper's)",
    )
    light.add_argument("--calib", type=int, help="number of calibration frames (default 60%%)")
    add_diffuse_argument(light, "near: ")
    add_effects_argument(light, "near: ")
    light.add_argument(
        "--right-views",
        action="store_true",
        help="near, a stereo capture (depth in mm): also fit each surface point's views from "
        "the right camera, which move V and keep L (a falloff cannot mimic them)",
    )
    add_workers_argument(light, "near: falloff sets")
    light.add_argument(
        "--facets",
        action="store_true",
        help="near: also the lobe about every tracked point's own facet (its normal read from "
        "the views where it shone) under the fitted light, sigma and F_tilde chosen on the "
        "calibration frames, judged on the held-out ones beside Lambert's (with the map)",
    )
    light.add_argument(
        "--facet-marginal",
        action="store_true",
        help="near: also the lobe with every tracked point's facet integrated out (a marginal "
        "likelihood; the facets' spread and the noise profiled) under the fitted light, on "
        "the calibration frames, with its halves; minutes on a 640 px capture (with the map); "
        "with --facets also the facet lobe at the marginal's width",
    )
    light.set_defaults(run=run_calibrate_light)


def run_calibrate_light(args: argparse.Namespace) -> int:
    from ..calibration import calibrate_near_light, named_falloff
    from ..estimation import default_albedo
    from ..io._atomic import atomic_write_json
    from ..lobes import diffuse_lobe_named
    from ..specular import highlight_alignment_line

    if args.model == "field":
        if args.diffuse != "lambertian":
            raise CtjaxError(
                "--diffuse is for the near light (the per-pixel light field is fitted with the "
                "paper's Lambertian + Cook-Torrance model)"
            )
        if args.right_views:
            raise CtjaxError(
                "--right-views is for the near light (a per-pixel light field is the left camera's)"
            )
        if args.workers is not None:
            raise CtjaxError("--workers is for the near light's falloff sets (--model near)")
        if args.facets or args.facet_marginal:
            option = "--facets" if args.facets else "--facet-marginal"
            raise CtjaxError(f"{option} is for the near light (--model near)")
        if args.effects not in (None, ["none"]):
            raise CtjaxError("--effects is for the near light (--model near)")
        if args.offset != "lens-plane":
            raise CtjaxError("--offset is for the near light (--model near)")
        return _calibrate_light_field(args)
    observations = load_observations(args)
    capture = observations.capture
    if (args.facets or args.facet_marginal) and (
        args.albedo or default_albedo(observations)
    ) != "map":  # refused before the calibration (minutes on a 640 px capture)
        option = "--facets" if args.facets else "--facet-marginal"
        raise CtjaxError(f"{option} needs the albedo map (depth and poses in every frame)")
    falloff = named_falloff(args.falloff, observations)
    effects = chosen_effects(args, capture)
    result = calibrate_near_light(
        observations,
        calibration=args.calib,
        falloff=falloff,
        albedo=args.albedo,
        progress=lambda m: print(f"[ctjax calibrate-light] {m}", flush=True),
        right_views=args.right_views,
        workers=args.workers,
        diffuse=diffuse_lobe_named(args.diffuse),
        offset_axes=args.offset.replace("-", "_"),
        effects=effects,
    )
    from ..effects._knee import knee_below_the_bend

    result.warnings.extend(filter(None, [knee_below_the_bend(result.model, capture)]))
    summary = result.to_json()
    if args.facets or args.facet_marginal:
        from ..heldout import HeldOutTracks

        split = HeldOutTracks.split(observations, args.calib)
        summary.update(
            split.model_facet_blocks(result.model, lobe=args.facets, marginal=args.facet_marginal)
        )
    atomic_write_json(args.json, in_length_unit(summary, capture.length_unit))
    offset = ", ".join(f"{v:.2f}" for v in summary["offset_mm"])
    if "offset_stderr_mm" in summary and summary.get("offset_detected", True):
        offset += " +- " + _uncertainties(summary["offset_stderr_mm"])
    if "offset_halves_stderr_mm" in summary:
        offset += "; even / odd frames +- " + _uncertainties(summary["offset_halves_stderr_mm"])
    if summary.get("offset_axes") == "lens_plane":
        offset += "; in the lens plane"
    if "offset_per_normal_tilt_mm" in summary:
        change = _uncertainties(summary["offset_per_normal_tilt_mm"])
        offset += f"; normals +-{summary['offset_normal_tilt_deg']:g} deg: +- {change}"
    print(
        f"light offset ({offset}) {label(capture.length_unit)}, "
        f"falloff {'+'.join(summary['falloff']) or 'none'}, "
        f"albedo {summary['albedo']}, status {summary['status']}; "
        f"RGB RMSE {result.calibration_rmse:.2f} (calibration), {result.heldout_rmse:.2f} "
        f"(held-out) levels, noise floor {result.noise_floor:.2f}; wrote {args.json}"
    )
    print(_brdf_line(summary, diffuse_lobe_named(args.diffuse)))
    if effects_line(result.model):
        print(effects_line(result.model))
    if "highlight_alignment" in summary:
        print(highlight_alignment_line(summary["highlight_alignment"]))
    if "facets" in summary:
        from ..fitting import facet_lobe_line

        print(facet_lobe_line(summary["facets"]))
    if "facet_marginal" in summary:
        from ..fitting import facet_marginal_line

        print(facet_marginal_line(summary["facet_marginal"]))
    if "facets_at_the_marginal_width" in summary:
        from ..fitting import at_the_marginal_width_line

        print(at_the_marginal_width_line(summary["facets_at_the_marginal_width"]))
    for warning in result.warnings:
        print(f"ctjax calibrate-light: warning: {warning}", file=sys.stderr)
    return 0


def _brdf_line(summary: dict, diffuse) -> str:
    """The fitted BRDF's parameters (and the lobes' gain where they show) in one line: the
    lobe's, then the diffuse term's shape (`diffuse`'s parameters, whichever lobe it is)."""
    from ..lobes._diffuse import diffuse_parameters

    shown = []
    for name in ("F_tilde", "sigma", *(name for name, _, _ in diffuse_parameters(diffuse))):
        value = summary.get(name)
        if isinstance(value, list):
            shown.append(f"{name} [{', '.join(f'{v:.4g}' for v in value)}]")
        elif isinstance(value, int | float):
            shown.append(f"{name} {value:.4g}")
    gain = summary.get("lobe_gain")
    if isinstance(gain, int | float):
        shown.append(f"lobe gain where it shows {100 * gain:.1f}%")
    return "BRDF: " + "; ".join(shown)


def _calibrate_light_field(args: argparse.Namespace) -> int:
    import io

    import numpy as np

    from ..calibration import calibrate_light_field
    from ..io._atomic import atomic_write_bytes, atomic_write_json

    observations = load_observations(args)
    capture = observations.capture
    result = calibrate_light_field(
        observations,
        calibration=args.calib,
        solver=field_solver(args.engine),
        albedo=args.albedo,
        progress=lambda m: print(f"[ctjax calibrate-light] {m}", flush=True),
    )
    summary = result.to_json()
    atomic_write_json(args.json, in_length_unit(summary, capture.length_unit))
    if args.npz is not None:
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **result.arrays)
        atomic_write_bytes(args.npz, buffer.getvalue())
    counts = summary["solver_status"]
    print(
        f"light field over {summary['solved_pixels']} pixels (converged {counts['converged']}, "
        f"max steps {counts['max_steps']}, failed {counts['failed']}), median "
        f"{summary['median_angle_from_view_deg']:.2f} deg from the view direction, "
        f"albedo {summary['albedo']}, status {summary['status']}; "
        f"RGB RMSE {result.calibration_rmse:.2f} (calibration), {result.heldout_rmse:.2f} "
        f"(held-out) levels, noise floor {result.noise_floor:.2f}; wrote {args.json}"
        + (f" and {args.npz}" if args.npz is not None else "")
    )
    for warning in result.warnings:
        print(f"ctjax calibrate-light: warning: {warning}", file=sys.stderr)
    return 0


def _uncertainties(values) -> str:
    """An offset's uncertainties per axis: two decimals, or one significant digit below
    0.01 (in median depths they are often that small; "?" where there is none)."""
    return ", ".join(
        "?" if v is None else f"{v:.2f}" if v == 0 or abs(v) >= 0.01 else f"{v:.1g}" for v in values
    )
