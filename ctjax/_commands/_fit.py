"""`ctjax fit`: the BRDF (rho_tilde, F_tilde, sigma) of a capture, its shape reconstructed
first when it has images only.
"""

import argparse
import sys
from pathlib import Path

from .._errors import CtjaxError
from .._units import in_length_unit
from ._args import (
    add_diffuse_argument,
    add_mask_arguments,
    effects_line,
    load_capture,
    mask_options,
    output_file,
    output_folder,
    positive_int,
)


def add_fit_parser(commands) -> None:
    from ..observations import DEFAULT_MAX_TRACKS

    fit = commands.add_parser("fit", help="estimate (rho_tilde, F_tilde, sigma) from a capture")
    fit.add_argument(
        "capture", type=Path, help="capture folder (without depth or normals: reconstructed first)"
    )
    fit.add_argument("--json", type=output_file, required=True, help="output JSON file")
    fit.add_argument(
        "--model",
        choices=("paper", "two-scales"),
        default="paper",
        help="paper: one Beckmann lobe (eq. 2); two-scales: two (eq. 3)",
    )
    add_diffuse_argument(fit)
    fit.add_argument(
        "--albedo",
        choices=("map", "uniform"),
        help="map: rho_tilde per surface point from all frames (default when every frame has "
        "depth and a pose, or the shape is reconstructed); uniform: one rho_tilde (the paper)",
    )
    fit.add_argument(
        "--albedo-maps",
        type=output_folder,
        metavar="DIR",
        help="write DIR/NAME.npy per frame: float32 (H, W, 3) rho_tilde per pixel, NaN where "
        "not estimated",
    )
    fit.add_argument(
        "--max-tracks",
        type=positive_int,
        metavar="N",
        help="with the albedo map: follow at most N surface points across frames (default "
        f"{DEFAULT_MAX_TRACKS}; more: steadier sigma and F_tilde on a reconstructed shape, "
        "slower)",
    )
    fit.add_argument(
        "--right-views",
        action="store_true",
        help="a stereo capture (depth in mm): also fit each surface point's views from the "
        "right camera, which move V and keep L (the left frames' light moves with them)",
    )
    fit.add_argument(
        "--no-shading",
        action="store_true",
        help="images only: keep SfM's shape (refined by the texture) without refining it by "
        "the shading (faster; sigma and F_tilde then off by up to tens of percent)",
    )
    fit.add_argument(
        "--patch",
        type=positive_int,
        default=1,
        metavar="K",
        help="fit the linear images averaged over K x K pixels (S and S~ found on the "
        "originals): sparkles (one facet a pixel) become the average lobe the model "
        "describes; 9 gave sigma within -7..+6%% on 5 of 6 synthetic sparkle captures "
        "(-22%% on the 6th), F_tilde only as a lower bound where sparkles clip; "
        "for sparkles only: it widens a solid highlight's lobe (default 1: no averaging)",
    )
    fit.add_argument(
        "--patch-kernel",
        choices=("box", "gaussian"),
        default="box",
        help="--patch: a K x K box, or a Gaussian of the box's spread (default box)",
    )
    fit.add_argument(
        "--facets",
        action="store_true",
        help="also the lobe about every tracked point's own facet (its normal read from the "
        "views where it shone) under this fit's light, sigma and F_tilde chosen on the "
        "first 60%% of the frames, judged on the rest beside Lambert's (with the map)",
    )
    fit.add_argument(
        "--facet-marginal",
        action="store_true",
        help="also the lobe with every tracked point's facet integrated out (a marginal "
        "likelihood; the facets' spread and the noise profiled) under this fit's light, on "
        "the first 60%% of the frames, with its halves: sigma within 6%% on synthetic truth, "
        "F_tilde an upper bound; minutes on a 640 px capture (with the map); with --facets "
        "also the facet lobe at the marginal's width, its F_tilde chosen and judged as "
        "--facets' (each estimator for what it reads consistently)",
    )
    fit.add_argument(
        "--effects",
        nargs="+",
        default=None,
        choices=("frame_exposure", "none"),
        metavar="EFFECT",
        help="image effects fitted with the BRDF: frame_exposure (a scope's auto-exposure: a "
        "gain per frame over the first's, with the albedo map; the other image effects: "
        "calibrate-light --effects), or none (one exposure, the paper's). Default: a gain "
        "per frame where the frames are brighter or darker than the others predict and the "
        "lobe moves with it, else none",
    )
    add_mask_arguments(fit)
    fit.set_defaults(run=run_fit)


def run_fit(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from .._threads import started
    from ..estimation import PAPER, TWO_SCALES, default_albedo, with_diffuse
    from ..estimation._capture_fit import fit_capture
    from ..io._atomic import atomic_write_json, atomic_write_npy
    from ..lobes import diffuse_lobe_named
    from ..observations import Observations
    from ..specular import highlight_alignment_line, sparkle_density_line, sparkle_density_summary

    capture = load_capture(args)
    shape = None
    if not any(frame.has_geometry for frame in capture.frames):
        from ..sfm import with_reconstructed_shape

        print(
            f"ctjax fit: {args.capture} has images only; reconstructing its shape by SfM "
            "first (in memory; `ctjax reconstruct` writes it to the capture)"
            + ("" if args.no_shading else ", then refining it by the shading"),
            file=sys.stderr,
        )
        capture, shape = with_reconstructed_shape(capture, shading=not args.no_shading)
        for warning in shape["warnings"]:
            print(f"ctjax fit: warning: {warning}", file=sys.stderr)
    family = with_diffuse(
        {"paper": PAPER, "two-scales": TWO_SCALES}[args.model], diffuse_lobe_named(args.diffuse)
    )
    if args.albedo_maps is not None and args.albedo == "uniform":
        raise CtjaxError("--albedo-maps needs the albedo map (--albedo map)")
    if args.max_tracks is not None and args.albedo == "uniform":
        raise CtjaxError("--max-tracks is for the albedo map (--albedo map)")
    if args.right_views and args.albedo == "uniform":
        raise CtjaxError("--right-views is for the albedo map (--albedo map)")
    if (args.facets or args.facet_marginal) and (args.albedo or default_albedo(capture)) != "map":
        option = "--facets" if args.facets else "--facet-marginal"  # refused before the fit
        raise CtjaxError(f"{option} needs the albedo map (depth and poses in every frame)")
    masks = mask_options(args)
    # The sets S and S~ found once: the intensity fit's, then the sparkle density's.
    observations = Observations.of(capture, masks)
    if args.patch > 1:
        from ..estimation._patches import patch_observations

        observations = patch_observations(capture, masks, args.patch, kernel=args.patch_kernel)
    # The sparkle density beside the fit, on a thread (it reads the images and S alone).
    sparkles = started(sparkle_density_summary, capture, observations.sets)
    estimate = fit_capture(
        observations,
        masks,
        family,
        albedo=args.albedo,
        max_points=args.max_tracks,
        right_views=args.right_views,
        effects=None if args.effects is None else tuple(e for e in args.effects if e != "none"),
    )
    if args.albedo_maps is not None:
        if "albedo" not in estimate.details or estimate.details["albedo"] != "map":
            raise CtjaxError(
                f"{args.capture}: --albedo-maps needs the albedo map, which needs depth and "
                "poses in every frame (poses.json), or a capture with images only"
            )
        for key, albedo in estimate.arrays.items():
            if key.startswith("albedo/"):
                name = key.removeprefix("albedo/")
                atomic_write_npy(args.albedo_maps / f"{name}.npy", albedo.astype(np.float32))
    result = estimate.to_json()
    result["sparkle_density"] = sparkles.result()
    if args.patch > 1:
        from ..estimation._patches import patch_summary

        result["patch"] = patch_summary(capture, observations.sets, args.patch, args.patch_kernel)
        result["warnings"] = [*result["warnings"], *result["patch"]["warnings"]]
    if shape is not None:
        result["shape"] = {"source": "ctjax reconstruct (structure-from-motion)", **shape}
    if args.facets or args.facet_marginal:
        from ..heldout import HeldOutTracks

        split = HeldOutTracks.split(observations)
        # With an exposure fitted: on the views with it undone (`model_facet_blocks`).
        result.update(
            split.model_facet_blocks(estimate.model, lobe=args.facets, marginal=args.facet_marginal)
        )
    atomic_write_json(args.json, in_length_unit(result, capture.length_unit))
    keys = ("rho_tilde", "F_tilde", "sigma", "rgb_rmse", "albedo", "status", *family.names)
    print(json.dumps({k: result[k] for k in result if k in keys}))
    samples = (
        f"{result['n_points']} tracked points"
        if result["albedo"] == "map"
        else f"{result['n_ring_pixels']} ring pixels"
    )
    if "diffuse_alone" in result:
        print(
            f"{args.diffuse} alone (no specular lobe): rgb_rmse "
            f"{result['diffuse_alone']['rgb_rmse']:.2f} levels"
        )
    print(
        f"Lambertian: rgb_rmse {result['lambertian']['rgb_rmse']:.2f} levels; {samples}; "
        f"wrote {args.json}" + (f" and {args.albedo_maps}/" if args.albedo_maps else "")
    )
    if effects_line(estimate.model):
        print(effects_line(estimate.model))
    exposure = result.get("exposure", {})
    if exposure.get("fitted") == "per_frame":
        one = exposure["one_exposure"]
        print(
            "ctjax fit: note: a gain per frame fitted (a scope's auto-exposure): with one "
            f"exposure the frames {', '.join(one['brightness_off'][:6])} are off in brightness "
            f"and the lobe moves with it (sigma {one.get('sigma', float('nan')):.4g}, "
            f"{one['status']}); "
            "--effects none keeps one exposure",
            file=sys.stderr,
        )
    halves = result.get("halves", {})
    if halves:
        names = [n for n in family.names if n in halves["even_frames"]]
        print(
            "stability: "
            + "; ".join(
                f"{n} {halves['even_frames'][n]:.4g} (even frames) / "
                f"{halves['odd_frames'][n]:.4g} (odd)"
                for n in names
            )
        )
    print(sparkle_density_line(result["sparkle_density"]))
    print(highlight_alignment_line(result["highlight_alignment"]))
    if "facets" in result:
        from ..fitting import facet_lobe_line

        print(facet_lobe_line(result["facets"]))
    elif result["albedo"] == "map":
        from ..fitting import facets_suggestion

        alignment = result["highlight_alignment"].get("status")
        suggestion = facets_suggestion(result["status"], alignment=alignment)
        if suggestion is not None:
            print(
                f"ctjax fit: note: {suggestion}: --facets (docs: real endoscopic video)",
                file=sys.stderr,
            )
    if "facet_marginal" in result:
        from ..fitting import facet_marginal_line

        print(facet_marginal_line(result["facet_marginal"]))
    if "facets_at_the_marginal_width" in result:
        from ..fitting import at_the_marginal_width_line

        print(at_the_marginal_width_line(result["facets_at_the_marginal_width"]))
    for warning in result["warnings"]:
        print(f"ctjax fit: warning: {warning}", file=sys.stderr)
    return 0
