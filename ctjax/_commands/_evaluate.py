"""`ctjax evaluate`: Lambertian against Cook-Torrance, their RGB errors and their shape from
shading.
"""

import argparse
import sys
from pathlib import Path

from .._errors import CtjaxError
from .._units import in_length_unit, label
from ._args import (
    add_diffuse_argument,
    add_effects_argument,
    add_workers_argument,
    chosen_effects,
    cook_torrance_estimator,
    effects_line,
    load_observations,
    output_file,
    output_folder,
)


def add_evaluate_parser(commands) -> None:
    evaluate = commands.add_parser(
        "evaluate", help="Lambertian vs Cook-Torrance: RGB error and shape from shading"
    )
    evaluate.add_argument("capture", type=Path, help="capture folder (with depth)")
    evaluate.add_argument("--json", type=output_file, required=True, help="output JSON file")
    evaluate.add_argument(
        "--plots", type=output_folder, help="folder for the paper's Fig. 4-7 plots"
    )
    evaluate.add_argument("--calib", type=int, help="number of calibration frames (default 60%%)")
    evaluate.add_argument(
        "--light",
        choices=("near", "colocated", "field"),
        default="near",
        help="Cook-Torrance's light: near (point light offset), colocated (paper's BRDF fit "
        "with L = V) or field (the paper's per-pixel light field)",
    )
    evaluate.add_argument(
        "--albedo",
        choices=("map", "uniform"),
        help="one albedo per surface point for both models (map; the default when every "
        "frame has depth and a pose) or one per model (uniform, the paper's)",
    )
    evaluate.add_argument(
        "--per-pixel-sfs",
        action="store_true",
        help="also run the paper's Cook-Torrance SfS (Tsai-Shah's normals refined per pixel, "
        "eq. 9) and report it beside the joint one",
    )
    evaluate.add_argument(
        "--no-sfs",
        action="store_true",
        help="RGB errors only: no shape from shading (it needs depth with relief to score)",
    )
    evaluate.add_argument(
        "--facets",
        nargs="?",
        choices=("auto", "on", "off"),
        const="on",
        default="auto",
        help="also the lobe about every tracked point's own facet (its normal read from the "
        "views where it shone), sigma and F_tilde chosen on the calibration frames, judged "
        "on the test frames beside Lambert's under the same light (with the map): on "
        "(--facets alone), off, or auto (default): where at least half of Cook-Torrance's "
        "test-frame residual lies within 7 px of the highlights, its lobe about the "
        "reconstruction's normals found or not (about a minute at 640x512 x 12)",
    )
    evaluate.add_argument(
        "--facet-marginal",
        action="store_true",
        help="with the facets judged: also the lobe with every tracked point's facet integrated "
        "out (a marginal likelihood on the calibration frames, as fit's) and the facet lobe at "
        "its width, its F_tilde chosen on the calibration frames and judged on the test frames "
        "(minutes more on a 640 px capture)",
    )
    add_diffuse_argument(evaluate, "Cook-Torrance's (near light): ")
    add_effects_argument(evaluate, "both models (near light, albedo map): ")
    add_workers_argument(evaluate, "test frames' shapes from shading")
    evaluate.set_defaults(run=run_evaluate)


def run_evaluate(args: argparse.Namespace) -> int:
    from ..diagnostics._budget import excess_by_angle_text
    from ..estimation import why_no_albedo_map
    from ..evaluation import evaluate, evaluation_plots
    from ..io._atomic import atomic_write_json
    from ..lobes import diffuse_lobe_named

    if args.diffuse != "lambertian" and args.light != "near":
        raise CtjaxError(
            f"--diffuse is for the near light's Cook-Torrance (--light near), not --light "
            f"{args.light} (the paper's fits are Lambertian + Cook-Torrance)"
        )
    if args.effects not in (None, ["none"]) and args.light != "near":
        raise CtjaxError(
            f"--effects is for the near light's Cook-Torrance (--light near), not --light "
            f"{args.light}"
        )
    if args.facet_marginal and args.facets == "off":
        raise CtjaxError("--facet-marginal is for the facets judged: not with --facets off")
    observations = load_observations(args)
    capture = observations.capture
    effects = chosen_effects(args, capture) if args.light == "near" else ()
    evaluation = evaluate(
        observations,
        calibration=args.calib,
        cook_torrance=cook_torrance_estimator(args.light),
        albedo=args.albedo,
        per_pixel_sfs=args.per_pixel_sfs,
        sfs=not args.no_sfs,
        workers=args.workers,
        progress=lambda m: print(f"[ctjax evaluate] {m}", flush=True),
        diffuse=diffuse_lobe_named(args.diffuse),
        facets={"on": True, "off": False}.get(args.facets, "auto"),
        facet_marginal=args.facet_marginal,
        effects=effects,
    )
    summary = evaluation.to_json()
    atomic_write_json(args.json, in_length_unit(summary, capture.length_unit))
    if args.plots:
        for path in evaluation_plots(observations, evaluation, args.plots).values():
            print(f"wrote {path}")
    print(
        "RGB RMSE (levels), calibration / test: Lambertian "
        f"{summary['lambertian_rgb_rmse_calibration']:.2f} / "
        f"{summary['lambertian_rgb_rmse_test']:.2f}, Cook-Torrance "
        f"{summary['cook_torrance_rgb_rmse_calibration']:.2f} / "
        f"{summary['cook_torrance_rgb_rmse_test']:.2f} (albedo {summary['albedo']})"
    )
    if effects_line(evaluation.cook_torrance.model):
        print(f"Cook-Torrance's {effects_line(evaluation.cook_torrance.model)}")
        from ..effects._knee import knee_below_the_bend

        below = knee_below_the_bend(evaluation.cook_torrance.model, capture)
        if below:
            print(f"ctjax evaluate: warning: {below}", file=sys.stderr)
    gain = summary["gain"]
    if "lobe_levels" in gain:
        parts = []
        if "light_levels" in gain:
            same = summary["lambertian_same_light_rgb_rmse_test"]
            effects = (
                " and image effects" if summary["models"]["cook_torrance"].get("effects") else ""
            )
            parts.append(
                f"{gain['light_levels']:.2f} from its light{effects} (Lambertian under the "
                f"same light{effects}: {same:.2f})"
            )
        if "diffuse_levels" in gain:
            alone = summary["diffuse_same_light_rgb_rmse_test"]
            parts.append(
                f"{gain['diffuse_levels']:.2f} from its diffuse term ({args.diffuse} alone "
                f"under the same light: {alone:.2f})"
            )
        parts.append(f"{gain['lobe_levels']:.2f} from the lobe")
        print(
            f"Cook-Torrance's gain on the test frames: {gain['total_levels']:.2f} levels = "
            + " + ".join(parts)
        )
    frames = summary.get("frames_rmse") or {}
    if frames.get("not_predicted"):
        named = ", ".join(f"{n} {frames['lambertian'][n]:.1f}" for n in frames["not_predicted"])
        print(
            f"frames the others do not predict (Lambertian, levels): {named}, against a median "
            f"of {frames['calibration_median_levels']:.1f} over the calibration frames: motion "
            "the poses and shape do not follow; no lobe explains them (frames_rmse in the JSON)"
        )
    if frames.get("brightness_off"):
        named = ", ".join(f"{n} {frames['brightness'][n]:.2f}x" for n in frames["brightness_off"])
        print(
            f"frames brighter or darker than the others predict ({frames['brightness_model']}, "
            f"measured over predicted): {named}: an exposure change the model lacks (a scope's "
            "auto-exposure: --effects frame_exposure fits one per frame) or motion it does not "
            "follow (frames_rmse in the JSON)"
        )
    if frames.get("not_judged"):
        print(
            f"ctjax evaluate: warning: no view of {', '.join(frames['not_judged'])} was judged "
            "(none of its pixels on a surface point the other frames see: its depth, normals "
            "or pose disagree with theirs); the RMSEs are over the other frames",
            file=sys.stderr,
        )
    for name, budget in (summary.get("residual_budget") or {}).items():
        if "rmse_levels" in budget:
            print(
                f"what is left of {name.replace('_', '-')}'s test-frame residual: "
                f"{100 * budget['highlight_share']:.0f}% within 7 px of the highlights "
                f"({100 * budget['highlight_pixels']:.0f}% of the views, "
                f"{budget['highlight_excess_levels']:+.1f} levels against the model"
                f"{excess_by_angle_text(budget.get('highlight_excess_by_angle', {}))}), "
                f"{100 * budget['gradient_share']:.0f}% with the image gradient "
                f"({budget['misregistration_px']:.2f} px)"
            )
    if "facets" in summary:
        from ..fitting import facet_lobe_line

        judged = summary["facets"].get("judged", "")
        if judged.startswith("by itself"):
            print(
                f"ctjax evaluate: note: the facet lobe judged {judged} (--facets off: not)",
                file=sys.stderr,
            )
        print(facet_lobe_line(summary["facets"]))
        if "facet_marginal" in summary["facets"]:
            from ..fitting import at_the_marginal_width_line, facet_marginal_line

            print(facet_marginal_line(summary["facets"]["facet_marginal"]))
            print(at_the_marginal_width_line(summary["facets"]["facets_at_the_marginal_width"]))
    if len(summary["lobes_judged"]["lobes"]) > 1:
        from ..evaluation import lobes_judged_lines

        print("\n".join(lobes_judged_lines(summary["lobes_judged"])))
    right = summary.get("right_views")
    if right is not None:
        figures = ", ".join(
            f"{name} {right[f'{key}_rgb_rmse']['right']:.2f} / "
            f"{right[f'{key}_rgb_rmse']['left']:.2f}"
            for name, key in (
                ("Lambertian", "lambertian"),
                ("Lambertian (same light)", "lambertian_same_light"),
                (f"{args.diffuse} alone (same light)", "diffuse_same_light"),
                ("Cook-Torrance", "cook_torrance"),
            )
            if f"{key}_rgb_rmse" in right
        )
        print(
            f"RGB RMSE (levels) on the right camera's views / the left views of the same "
            f"points, calibration frames ({right['views']} views): {figures}"
        )
    fitted = summary["models"]["cook_torrance"]
    for flagged in fitted["undetermined"]:
        print(
            f"ctjax evaluate: warning: Cook-Torrance's fit is {fitted['status']}: "
            f"{flagged['reason']}",
            file=sys.stderr,
        )
    # Why the uniform albedo was fitted where the map was meant: a warning, not a note.
    unmapped = why_no_albedo_map(observations) if args.albedo is None else None
    for note in summary["notes"]:
        kind = "warning" if note == unmapped else "note"
        print(f"ctjax evaluate: {kind}: {note}", file=sys.stderr)
    if summary["lambertian_sfs_error_mm"] is not None:
        models = [("Lambertian", "lambertian"), ("Cook-Torrance", "cook_torrance")]
        if args.per_pixel_sfs:
            models.append(("the paper's per-pixel refinement", "cook_torrance_per_pixel"))
        unit = label(capture.length_unit)
        for what, where in (("mean", ""), ("mean near highlights", "_near_highlights")):
            errors = (summary[f"{key}_sfs_error{where}_mm"] for _, key in models)
            figures = ", ".join(
                f"{name} {float('nan') if e is None else e:.2f}"
                for (name, _), e in zip(models, errors, strict=True)
            )
            print(f"SfS 3D error ({what}, {unit}): {figures}")
    print(f"wrote {args.json}")
    return 0
