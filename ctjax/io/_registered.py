"""Frames that structure from motion did not register: left out of the fits, with a note.

`ctjax reconstruct` writes depth, normals and a pose for the frames it registers and lists
the others in `reconstruction.json`'s `unregistered` (their images stay in the capture:
it may write in place, and a user's images are not deleted). Every estimator needs each
frame's shape, so the commands that fit leave those frames out and say which, as `ctjax
fit` does on a capture of images only (`ctjax.sfm.with_reconstructed_shape`). Before,
one frame short was enough to stop every command after `reconstruct`: on 12 frames of a
second sinus video (every 10th of 120, `benchmarks/real_video.py`) 11 registered, and
`fit` ended in "no depth or normals for frame(s) 00002721; ... reconstruct it first" on a
capture just reconstructed (on the same video's 381 frames taken 31 apart, 3 of 12).
"""

import dataclasses
import json

from ._capture import Capture

# How many of the left-out frames a note names.
_NAMED = 5


def registered_frames(capture: Capture) -> tuple[Capture, str | None]:
    """`capture` without the frames that `ctjax reconstruct` could not register (listed
    in its `reconstruction.json` and without depth or normals) where other frames have their
    shape, and a note naming them; the capture as it is, and None, otherwise (every frame
    with its shape, none, or a frame without one that the report does not list)."""
    missing = [frame.name for frame in capture.frames if not frame.has_geometry]
    if not missing or len(missing) == len(capture.frames):
        return capture, None
    try:
        report = json.loads((capture.root / "reconstruction.json").read_text())
        unregistered = set(report.get("unregistered") or ())
    except (OSError, ValueError, AttributeError, TypeError):
        return capture, None
    if not set(missing) <= unregistered:
        return capture, None
    kept = tuple(frame for frame in capture.frames if frame.has_geometry)
    named = ", ".join(missing[:_NAMED]) + (", ..." if len(missing) > _NAMED else "")
    note = (
        f"{len(missing)} of {len(capture.frames)} frames did not register in ctjax reconstruct "
        f"({named}; its reconstruction.json): left out, the other {len(kept)} used (frames "
        "closer together in time share more features and register)"
    )
    return dataclasses.replace(capture, frames=kept), note
