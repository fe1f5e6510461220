"""`ctjax masks`: the specular set S and its ring S~ of every frame, as PNG masks."""

import argparse
from pathlib import Path

from ._args import add_mask_arguments, load_capture, mask_options, output_folder


def add_masks_parser(commands) -> None:
    masks = commands.add_parser("masks", help="specular set S and ring S~ of every frame")
    masks.add_argument("capture", type=Path, help="capture folder")
    masks.add_argument("--out", type=output_folder, required=True, help="folder for the PNG masks")
    add_mask_arguments(masks)
    masks.set_defaults(run=run_masks)


def run_masks(args: argparse.Namespace) -> int:
    import numpy as np

    from ..io._images import write_mask
    from ..specular import capture_sets

    capture = load_capture(args, registered_only=False)  # S of every frame
    sets = capture_sets(capture, mask_options(args))
    for frame, s in zip(capture.frames, sets, strict=True):
        for kind in ("specular", "ring"):
            write_mask(args.out / kind / f"{frame.name}.png", getattr(s, kind))
        write_mask(args.out / "saturated" / f"{frame.name}.png", s.clipped)
        write_mask(args.out / "fov" / f"{frame.name}.png", frame.visible)
        outside = int((~frame.visible).sum())
        clipped = s.clipped.sum(axis=(0, 1))
        print(
            f"{frame.name}: {int(s.specular.sum())} specular, {int(s.ring.sum())} ring pixels; "
            "clipped outside S: "
            + ", ".join(f"{c} {n}" for c, n in zip("RGB", clipped, strict=True))
            + (f"; {outside} outside the field of view" if outside else "")
        )
    total = int(np.sum([s.ring.sum() for s in sets]))
    print(f"wrote masks of {len(sets)} frame(s) to {args.out} ({total} ring pixels in all)")
    return 0
