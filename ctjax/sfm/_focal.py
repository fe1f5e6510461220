"""The focal length from the frames themselves, for videos without a calibration.

A video without a calibration is read with a guessed pinhole camera (`ctjax import
--camera guess`: fx = fy = 0.8 width): a wrong focal length
tilts every view ray, and with it every angle the BRDF is read at.
Bundle adjustment can refine it (COLMAP's `ba_refine_focal_length`, the principal point
held), but whether the frames determine it depends on the camera's motion and the scene's
relief: with little of either, the focal length trades against depth and the refinement
ends wherever it started. So it is refined twice, from the given focal length and from
`SECOND_START` times it, and kept only when both end within `AGREEMENT` of each other and
the pixels' aspect fx / fy stays within `AGREEMENT` of the given one; otherwise the given
camera is kept and the report says the frames do not determine it.

Measured (the refined fx from several starts, `benchmarks/focal_length.py`): synthetic
captures 320x256 x 5 from 0.3, 0.5 and 0.7 width: 287.4-287.7 px for the true 288
(-0.2%); 192x160 x 4 from 0.5, 0.8 and 1.1 width: 175.0-176.8 px for 172.8 (+1.3..+2.3%);
12 frames of the shared cholecystectomy video at 640x360 from 0.5, 0.8 and 1.25 width:
373-377 px (0.58-0.59 width; the guess is 512), fx / fy 1.008. Where it fails: 12 frames
of the shared sinus sequence, calibrated at fx = fy = 225.7 px (0.353 width): 90.9 / 116.2
px from the calibration itself, 108.4 / 134.6 from 0.25 width, 10985 / 1792 from 0.5
width (6 of 12 frames registered): the frames do not determine it, and the check says so.
"""

import dataclasses

from .._camera import Camera
from .._errors import CaptureError
from ._colmap import SparseModel, sparse_reconstruction

FOCAL_CHOICES = ("fixed", "refine")
# The second refinement starts this many times the given focal length, and the two must
# end within this relative difference (each of fx, fy) for the refined one to be kept.
SECOND_START = 1.5
AGREEMENT = 0.02


def sparse_with_focal(
    capture, focal: str, progress=None, verbose: bool = False
) -> tuple[SparseModel, Camera, dict]:
    """SfM of `capture` with its camera's focal length `"fixed"` or `"refine"`d (module
    doc): the sparse model, the camera the rest of the reconstruction uses, and the
    report's `focal` block (`status`: "given", "refined" or "undetermined")."""
    if focal not in FOCAL_CHOICES:
        raise CaptureError(f"focal must be one of {', '.join(FOCAL_CHOICES)}, got {focal!r}")
    camera = capture.camera
    given = [float(camera.fx), float(camera.fy)]
    if focal == "fixed":
        sparse = sparse_reconstruction(camera, capture.frames, progress=progress, verbose=verbose)
        return sparse, camera, {"status": "given", "fx_fy_px": given}
    from ..io import read_camera

    distorted = read_camera(capture.root / "camera.json").distortion is not None
    if capture.stereo is not None or distorted:
        raise CaptureError(
            f"{capture.root}: --focal refine is for an uncalibrated camera (a guessed pinhole); "
            "this one is calibrated (stereo or lens distortion): keep its focal length"
        )
    say = progress or (lambda message: None)
    say(f"the focal length refined from {given[0]:.1f} px and from {SECOND_START} times it")
    runs = []
    for factor in (1.0, SECOND_START):
        start = dataclasses.replace(camera, fx=camera.fx * factor, fy=camera.fy * factor)
        runs.append(
            sparse_reconstruction(
                start, capture.frames, refine_focal=True, progress=progress, verbose=verbose
            )
        )
    (first, second) = (list(run.focal_px) for run in runs)
    spread = max(abs(a / b - 1) for a, b in zip(first, second, strict=True))
    # The pixels' aspect (fx / fy) is known where the focal length is not: a refinement that
    # changes it is the focal length trading against depth, not measured.
    aspect = abs((first[0] / first[1]) / (given[0] / given[1]) - 1)
    report = {
        "given_fx_fy_px": given,
        "refined_fx_fy_px": first,
        "second_start_fx_fy_px": second,
        "second_start_factor": SECOND_START,
        "relative_difference": spread,
        "aspect_change": aspect,
        "agreement_required": AGREEMENT,
    }
    if spread <= AGREEMENT and aspect <= AGREEMENT:
        refined = dataclasses.replace(camera, fx=first[0], fy=first[1])
        say(f"  fx, fy = {first[0]:.1f}, {first[1]:.1f} px (both starts within {spread:.1%})")
        return runs[0], refined, {"status": "refined", "fx_fy_px": first, **report}
    why = (
        f"the focal length refined from two starts ended {spread:.1%} apart (fx {first[0]:.1f} "
        f"and {second[0]:.1f} px) and changed the pixels' aspect fx / fy by {aspect:.1%} "
        f"(both must stay within {AGREEMENT:.0%})"
    )
    say(f"  {why}: the given focal length is kept")
    sparse = sparse_reconstruction(camera, capture.frames, progress=progress, verbose=verbose)
    report["note"] = (
        f"{why}: the frames do not determine it (too little motion or relief); the given "
        "camera is kept"
    )
    return sparse, camera, {"status": "undetermined", "fx_fy_px": given, **report}


def with_focal(camera_json: dict, focal: dict) -> dict:
    """camera.json's content with the refined focal length of a `focal` report (unchanged
    unless its status is "refined")."""
    if focal.get("status") != "refined":
        return camera_json
    fx, fy = focal["fx_fy_px"]
    return {**camera_json, "fx": fx, "fy": fy}
