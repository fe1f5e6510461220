"""What several commands share: argument types and groups (`--max-tracks`'s positive
integer, the files and folders a command writes, the specular set's options, `--falloff`),
the capture loaded with its notes, and the command line's words for objects (`--engine`,
`--light`), in one place.
"""

import argparse
import math
import sys
from pathlib import Path

from .._errors import CtjaxError


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return value


def output_file(text: str) -> Path:
    """The type of an argument naming a file a command writes (`--json`, `--npz`): refused
    when parsed, before any work, where it is a folder or lies under a file."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a directory")
    _check_parent_folders(path, text)
    return path


def output_folder(text: str) -> Path:
    """The type of an argument naming a folder a command writes into (`--out`, `--plots`):
    refused when parsed, before any work, where it is a file or lies under one."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: exists and is not a folder")
    _check_parent_folders(path, text)
    return path


def _check_parent_folders(path: Path, text: str) -> None:
    """The nearest existing folder above `path` (the rest is created) must be a folder."""
    for parent in path.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f"{text}: {parent} is not a folder")
            return


def load_capture(args: argparse.Namespace, registered_only: bool = True):
    """`args.capture` loaded, with its notes (how its images were decoded) on stderr;
    `registered_only`: without the frames `ctjax reconstruct` did not register, with a note
    (`ctjax.io.registered_frames`)."""
    from ..io import load_capture as load
    from ..io import registered_frames

    capture = load(args.capture)
    notes = list(capture.notes)
    if registered_only:
        capture, left_out = registered_frames(capture)
        notes += [left_out] if left_out else []
    for note in notes:
        print(f"ctjax {args.command}: note: {note}", file=sys.stderr)
    return capture


def load_observations(args: argparse.Namespace):
    """`args.capture` loaded (`load_capture`) and made into observations, once for the whole
    command: every estimator and figure of the command is given these."""
    from ..observations import Observations

    return Observations.of(load_capture(args))


def add_effects_argument(parser: argparse.ArgumentParser, prefix: str = "") -> None:
    """`--effects NAME ...`: image effects fitted with the rest, by their candidates' names
    (`ctjax.effects.image_effect_names`; checked when the command runs); `none` for none;
    not given: those the frames show (`chosen_effects`)."""
    parser.add_argument(
        "--effects",
        nargs="+",
        default=None,
        metavar="EFFECT",
        help=f"{prefix}image effects fitted with the rest: frame_exposure (a scope's "
        "auto-exposure: a gain per frame, each held-out frame's fitted on its own views), "
        "vignetting, ambient, camera_gamma, srgb_response, knee, or none. Default: the knee "
        "where the frames show one (a channel that rises markedly slower above a bright level "
        "than below it: the capture's note names it), else none",
    )


def chosen_effects(args: argparse.Namespace, capture) -> tuple:
    """`--effects` as given (`none`: no effects), or, not given, the effects the frames show:
    the knee `load_capture` found where it found one (`Capture.knees`), started there and
    compressing those channels only (`ctjax.effects._knee.knee_of`), with a note on stderr.
    On a second sinus video's 28 frames `evaluate --no-sfs` 11.61 -> 9.84 levels on the test
    frames."""
    from ..effects._knee import knee_of

    if args.effects is not None:
        if "none" in args.effects and len(args.effects) > 1:
            raise CtjaxError(f"--effects none fits no effects: not with others ({args.effects})")
        return tuple(e for e in args.effects if e != "none")
    knee = knee_of(capture)
    if knee is None:
        return ()
    channels = "".join("RGB"[c] for c, on in enumerate(knee.compressed) if on)
    print(
        f"ctjax {args.command}: note: the camera's knee in {channels} (the note above) is fitted "
        "with the model, the other channels not compressed; --effects knee fits it in all three, "
        "--effects none fits none",
        file=sys.stderr,
    )
    return (knee,)


def effects_line(model) -> str | None:
    """The fitted image effects of `model` in one line (a frame's exposure as a factor over
    the first frame's), or None without effects."""
    from .._json import named_parameters

    if not tuple(getattr(model, "effects", ())):
        return None
    parts = []
    for name, value in named_parameters(tuple(model.effects)).items():
        if name == "log_exposure":
            factors = " ".join(f"{math.exp(v):.2f}" for v in [0.0, *value])
            parts.append(f"each frame's exposure over the first's {factors}")
        else:
            values = value if isinstance(value, list) else [value]
            parts.append(f"{name} {' '.join(f'{v:.3g}' for v in values)}")
    return "image effects: " + "; ".join(parts)


def add_diffuse_argument(parser: argparse.ArgumentParser, prefix: str = "") -> None:
    """`--diffuse NAME`: the diffuse term, one of the lobes `ctjax.lobes.diffuse_lobes`
    finds (a new one's file offers it here)."""
    from ..lobes import diffuse_lobes

    parser.add_argument(
        "--diffuse",
        choices=tuple(diffuse_lobes()),
        default="lambertian",
        help=f"{prefix}the diffuse term: lambertian (the paper's cosine law) or a rough "
        "diffuse lobe whose shape is fitted with the rest (oren-nayar: Oren-Nayar's "
        "V-cavities, flatter shading, as tissue's is on real laparoscope and sinus frames) "
        "(default: lambertian)",
    )


def add_mask_arguments(parser: argparse.ArgumentParser) -> None:
    from ..specular import DEFAULT_MIN_SPECK_PX, DEFAULT_RING_PX, HLSThresholds, WhiterThanTissue

    whiter, hls = WhiterThanTissue(), HLSThresholds()
    group = parser.add_argument_group(
        "specular set S and ring S~",
        "S: 'whiter' (default) takes pixels bright and whiter than the tissue around them, "
        "or clipped; 'hls' is the paper's rule (HLS lightness and saturation thresholds)",
    )
    group.add_argument(
        "--highlights",
        choices=("whiter", "hls"),
        default="whiter",
        help="the rule that finds S (default: whiter)",
    )
    group.add_argument(
        "--whiteness",
        type=float,
        default=whiter.whiteness,
        help="whiter: fraction of the way from the local tissue's colour to white "
        f"(default {whiter.whiteness})",
    )
    group.add_argument(
        "--contrast",
        type=float,
        default=whiter.contrast,
        help="whiter: luminance at least this times the local tissue's "
        f"(default {whiter.contrast})",
    )
    group.add_argument(
        "--lightness",
        type=float,
        default=None,
        help=f"hls: HLS lightness at least this (default {hls.lightness})",
    )
    group.add_argument(
        "--saturation",
        type=float,
        default=None,
        help=f"hls: HLS saturation at most this (default {hls.saturation})",
    )
    group.add_argument(
        "--ring-px",
        type=float,
        default=DEFAULT_RING_PX,
        help="S~: non-specular pixels within this distance of S "
        f"(default and paper: {DEFAULT_RING_PX})",
    )
    group.add_argument(
        "--min-speck",
        type=int,
        default=DEFAULT_MIN_SPECK_PX,
        help="drop specular specks smaller than this many pixels, 0 keeps all "
        f"(default {DEFAULT_MIN_SPECK_PX})",
    )


def mask_options(args: argparse.Namespace):
    from ..specular import HLSThresholds, MaskOptions, WhiterThanTissue

    if args.highlights == "hls":
        hls = HLSThresholds()
        rule = HLSThresholds(
            hls.lightness if args.lightness is None else args.lightness,
            hls.saturation if args.saturation is None else args.saturation,
        )
    else:
        if args.lightness is not None or args.saturation is not None:
            raise CtjaxError(
                "--lightness and --saturation set the paper's rule: add --highlights hls"
            )
        rule = WhiterThanTissue(whiteness=args.whiteness, contrast=args.contrast)
    return MaskOptions(rule, args.ring_px, args.min_speck)


def add_workers_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """`--workers N`: how many of `what` are fitted at once, on threads."""
    parser.add_argument(
        "--workers",
        type=positive_int,
        metavar="N",
        help=f"{what} fitted at once, on threads (default: the cores this process may use, "
        "at most 4); the results do not depend on it",
    )


def add_falloff_argument(parser) -> None:
    parser.add_argument(
        "--falloff",
        default="auto",
        # ctjax.calibration._near_light_models.FALLOFF_NAMES (not imported here: it loads JAX)
        choices=("auto", "none", "inverse_square", "spot", "inverse_square+spot"),
        help="falloffs of the near light (auto: chosen on held-out frames)",
    )


# The command line's words for objects, in one place.


def field_solver(engine: str):
    """`--engine`: the light field's per-pixel solver."""
    from ..calibration import FIELD_SOLVER, ClosedFormLM

    return {"optimistix": FIELD_SOLVER, "closed-form": ClosedFormLM(iterations=10)}[engine]


def cook_torrance_estimator(light: str):
    """`--light`: how `ctjax evaluate` fits Cook-Torrance and its light."""
    from ..calibration import calibrate_light_field, calibrate_near_light
    from ..evaluation import fit_colocated

    return {
        "near": calibrate_near_light,
        "colocated": fit_colocated,
        "field": calibrate_light_field,
    }[light]
