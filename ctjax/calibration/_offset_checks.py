"""Where the near light's offset is placed from, and what checks it beyond its standard error.

On a shape `ctjax reconstruct` made, the light is fitted to the views away from the
highlights and from the surface's edge, where the surface was measured
(`away_from_highlights`); the offset is fitted again on the even and on the odd frames
apart (`offset_halves`) and, on a reconstructed shape, with every normal tilted toward and
away from the optical axis (`offset_normal_tilt`); and an offset further from the lens than
an endoscope's light can be is said to be no light position (`far_offset`).
Used by `near_light_map` (`_near_light.py`).
"""

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np

from .._units import label
from ..observations import Observations

# The margin (px) about S and the clipped pixels within which `ctjax reconstruct` places the
# surface by no texture (`ctjax.sfm._photometric.MASK_DILATE_PX`; a test checks they agree).
HIGHLIGHT_MARGIN_PX = 8


def reconstructed(capture: Observations) -> bool:
    """Whether the capture's shape is `ctjax reconstruct`'s (its report is in the folder)."""
    root = capture.capture.root
    return root is not None and (Path(root) / "reconstruction.json").is_file()


def edge_margin_px(capture: Observations) -> float:
    """The band along the edge of a reconstructed surface (the image's, or where its depth
    ends) in which the surface is extrapolated: one knot spacing of its splines
    (`reconstruction.json`; 0 where it does not say)."""
    try:
        report = json.loads((Path(capture.capture.root) / "reconstruction.json").read_text())
        return float(report["surface"]["knot_spacing_px"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0.0


# The share of the views that must lie away from the highlights for them to place the light
# alone (77-91% on reconstructed synthetic stereo captures, 66-71% on the shared real ones).
MIN_PLACING_SHARE = 0.5


def placing_views(capture: Observations, tracks, right=None):
    """The tracks the light is placed by, and a warning or None: on a reconstructed shape
    the views away from the highlights (`away_from_highlights`), unless fewer than
    `MIN_PLACING_SHARE` of the views are, then every view (and the warning says so); on any
    other shape every view."""
    if not reconstructed(capture):
        return tracks, None
    placing = away_from_highlights(capture, tracks, right)
    share = np.sum(placing.weight > 0) / max(np.sum(tracks.weight > 0), 1)
    if share >= MIN_PLACING_SHARE:
        return placing, None
    return tracks, (
        f"the light is placed by every view of the reconstructed shape: only {share:.0%} of "
        f"them lie farther than {HIGHLIGHT_MARGIN_PX} px from their frame's highlights and "
        f"{edge_margin_px(capture):g} px from the surface's edge (at least "
        f"{MIN_PLACING_SHARE:.0%} wanted), and the surface there is bridged or extrapolated "
        "by the reconstruction, not measured: the offset may be biased"
    )


def away_from_highlights(capture: Observations, tracks, right=None):
    """`tracks` with every view within `HIGHLIGHT_MARGIN_PX` of its frame's S or clipped
    pixels, or within `edge_margin_px` of its surface's edge (the image's, or where the
    frame's depth ends), weighted 0. `right`: which
    observations are a stereo capture's right views; one goes with the same point's left
    view at the same instant (weighted 0 where that one is, or where the left camera did not
    see the point there).

    There a reconstructed surface is no measurement: the texture that places it is clipped
    or moves with the light, so `ctjax reconstruct` masks it and the spline bridges it, and
    its normals there are off by more (`ctjax synth --stereo 5 --light-offset 4 -3 0
    --inverse-square`, reconstructed: 2 degrees in the median on S and the clipped pixels,
    0.6-1.5 within 8 px of them, 0.5 beyond). Those are the views where the specular
    shows most, and a light fitted to them moves to where those normals put the
    highlights: the offset 1.72 mm off the truth with them, 0.81 without (5 frames at
    320x256); on 8 frames, seeds 1-3: 0.58 -> 0.08, 0.50 -> 0.20, 1.07 -> 0.50 mm; on the
    5 frames' shape refined by the shading (`reconstruct --shading near`) 0.65 -> 0.42 mm.
    The BRDF, refitted on every view with the light held, moves by 1-5% in F_tilde (towards
    the truth on 3 of the 4) and at most 1.5% in sigma. On the true shape the same views are
    good data (0.04 mm off with them, 0.15 without): only a reconstructed shape's are set
    aside, and only to place the light.

    Along its edge a reconstructed surface has points on one side only and the spline's
    penalty straightens it: within a knot spacing of the edge the steepest quarter
    of its normals is 1.2-5.4 degrees flatter than the truth (`benchmarks/surface_bias.py`,
    the spline fitted to exact depths), 0.02-0.62 inside. Set aside there too, the light in
    the lens plane on `ctjax synth --stereo 5 --light-offset 4 -3 0 --inverse-square`
    (320x256 x 5, reconstructed, seeds 0-3) went from 0.09 / 0.01 / 1.26 / 0.18 mm off to
    0.11 / 0.02 / 0.38 / 0.17; at 640x512 from 0.09 / 0.04 / 0.29 / 0.11 mm to 0.09 / 0.04 /
    0.11 / 0.12. (With the offset free along the axis, 320x256: 0.81 / 0.12 / 1.31 / 0.28
    mm without the band, 0.86 / 0.11 / 0.36 / 0.32 with the image's edge set aside.)"""
    pixel = np.einsum("pmc,pmcd->pmd", tracks.corner_weight, tracks.corner_pixel)
    near = np.zeros(tracks.observed.shape, bool)
    margin = edge_margin_px(capture)
    for index, (sets, frame) in enumerate(zip(capture.sets, capture.frames, strict=True)):
        at = tracks.observed & (tracks.frame == index)
        if right is not None:
            at &= ~right
        if not at.any():
            continue
        u = np.clip(np.rint(pixel[at][:, 0]).astype(int), 0, sets.specular.shape[1] - 1)
        v = np.clip(np.rint(pixel[at][:, 1]).astype(int), 0, sets.specular.shape[0] - 1)
        bright = sets.specular | sets.saturated
        if bright.any():
            distance = cv2.distanceTransform((~bright).astype(np.uint8), cv2.DIST_L2, 5)
            near[at] = distance[v, u] <= HIGHLIGHT_MARGIN_PX
        if margin > 0:
            near[at] |= _to_the_surfaces_edge(frame.depth)[v, u] < margin
    if right is not None:
        left = tracks.observed & ~right
        for index in np.unique(tracks.frame[right]):
            seen = np.any(left & (tracks.frame == index), axis=1)
            close = np.any(near & left & (tracks.frame == index), axis=1)
            at = right & (tracks.frame == index)
            near[at] = np.broadcast_to((close | ~seen)[:, None], at.shape)[at]
    return dataclasses.replace(tracks, weight=np.where(near, 0.0, tracks.weight))


def _to_the_surfaces_edge(depth: np.ndarray) -> np.ndarray:
    """Each pixel's distance (px) to the nearest pixel without depth or off the image: where
    the reconstructed surface's support ends."""
    support = np.pad(np.isfinite(depth), 1).astype(np.uint8)
    return cv2.distanceTransform(support, cv2.DIST_L2, 5)[1:-1, 1:-1]


# The frames are split in two (even and odd) to check the offset when there are at least this
# many: two per half, as the map needs for a point's albedo.
MIN_FRAMES_FOR_HALVES = 4
# The halves' spread that is more than this many times the offset's standard error is not
# the image noise's.
HALVES_BEYOND_NOISE = 3.0


# An endoscope's light leaves it at its tip, beside the lens: a fibre bundle a few
# millimetres across, a da Vinci's guides within 5 mm of the lens, against working distances
# of 30-100 mm. An offset beyond this share of the working distance is no such light.
FAR_OFFSET = 0.3


def far_offset(offset: np.ndarray, working_distance: float, unit: str) -> str | None:
    """A warning where the fitted offset lies further from the lens than `FAR_OFFSET` working
    distances (the median depth), else None: the fit then puts the light where no
    endoscope's is, and the offset stands in for something the model lacks (a falloff of
    another shape: on the shared sinus's twelve consecutive frames, with inverse-square and
    spot falloff, the offset was (-0.01, 0.31, -1.08) median depths, 1.17 working distances:
    a light behind the lens, the even and the odd frames agreeing within 0.03)."""
    distance = float(np.linalg.norm(offset)) / working_distance
    if not distance > FAR_OFFSET:
        return None
    return (
        f"the light's offset {np.round(offset, 2).tolist()} {label(unit)} is "
        f"{distance:.2f} working distances from the lens (more than {FAR_OFFSET:g}): an "
        "endoscope's light leaves it "
        "at its tip, beside the lens, so this offset stands in for something the model lacks "
        "(a falloff of another shape, the camera's response, vignetting); it is not where "
        "the light is"
    )


def offset_halves(result, tracks, fit, reported) -> None:
    """The chosen model refitted on the views of the even and of the odd frames alone (the
    same tracks, the other half's views weighted 0: the refit's compiled program), and the
    offset's uncertainty they show.

    The offset's standard error counts the image noise only; an error of the shape (the
    normals under the highlights, where the texture that places the surface is clipped, are
    2 degrees off on a reconstructed synthetic stereo capture against 0.5 elsewhere) biases
    the offset by far more: 0.50 mm off the truth with standard errors of 0.02-0.04 mm
    (`ctjax synth --stereo 5 --light-offset 4 -3 0 --inverse-square --frames 8 --seed 2`,
    then `reconstruct`). Each frame's surface is its own, so the halves see partly
    independent shape errors: for two halves a and b, |a - b| / 2 estimates the whole fit's
    standard error (there (0.55, 0.42, 0.39) mm; 1.41 mm along the axis on 5 frames, where
    the offset is 1.69 mm off along it). It is reported beside the standard error, and a
    warning says so where it is more than `HALVES_BEYOND_NOISE` times as large. An error
    every frame's surface shares moves both halves alike and is not seen: on the one world
    surface of `reconstruct --shading near` the halves gave (0.11, 0.03, 0.37) mm for an
    offset (0.62, 0.10, 0.17) mm off. On the true shape of the 5 frames the halves still
    gave 0.24 mm along the axis against a standard error of 0.05 (the offset 0.04 mm off):
    the noise is not all that moves the offset there either."""
    frames = np.unique(tracks.frame[tracks.observed & (tracks.frame >= 0)])
    if len(frames) < MIN_FRAMES_FOR_HALVES:
        return
    halves = []
    for parity in (0, 1):
        keep = tracks.observed & (tracks.frame >= 0) & (tracks.frame % 2 == parity)
        halves.append(dataclasses.replace(tracks, weight=np.where(keep, tracks.weight, 0.0)))
    refitted = _refitted_offsets(result, fit, halves)
    if refitted is None:
        return
    offsets, spread = refitted
    result.details["offset_halves_mm"] = dict(
        zip(("even_frames", "odd_frames"), (o.tolist() for o in offsets), strict=True)
    )
    result.details["offset_halves_stderr_mm"] = spread.tolist()
    _beyond_noise(
        result,
        spread,
        reported,
        "(half the difference between the even and the odd frames' fits)",
        ", which counts the image noise only: something else moves it (the shape's error, the "
        "normals under the highlights most, or a parameter the fit trades against it); take "
        "the halves' figure as the offset's uncertainty",
    )


# The normals' error a reconstruction shares between its frames: each view's spline smooths
# its depth map, and smoothing turns the normals toward the optical axis where the surface is
# steep (`ctjax synth --stereo 5 --light-offset 4 -3 0 --inverse-square`, reconstructed: the
# steepest quarter of the normals 0.24-0.57 degrees flatter than the truth, the least steep
# 0.19-0.32 degrees steeper, 0.5 degrees off in the median away from the highlights). The
# offset is refitted with every normal tilted by this much toward and away from the axis.
NORMAL_TILT_DEG = 0.5


def tilted_normals(tracks, degrees: float):
    """`tracks` with every normal turned by `degrees` toward the camera's optical axis (away
    from it where negative; never past it). The normals are in the camera's frame, facing
    the camera (negative z)."""
    normal = np.asarray(tracks.corner_normal, float)
    axis = np.array([0.0, 0.0, -1.0])
    cos = np.clip(normal @ axis, -1.0, 1.0)
    across = axis - cos[..., None] * normal
    length = np.linalg.norm(across, axis=-1, keepdims=True)
    across = np.divide(across, length, out=np.zeros_like(across), where=length > 1e-12)
    step = np.radians(degrees)
    step = np.minimum(step, np.arccos(cos)) if step > 0 else np.full(cos.shape, step)
    turned = normal * np.cos(step)[..., None] + across * np.sin(step)[..., None]
    size = np.linalg.norm(turned, axis=-1, keepdims=True)
    unit = np.linalg.norm(normal, axis=-1, keepdims=True) > 0.5  # not padding
    turned = np.where(unit, turned / np.where(unit, size, 1.0), normal)
    return dataclasses.replace(tracks, corner_normal=turned.astype(tracks.corner_normal.dtype))


def offset_normal_tilt(result, tracks, fit, reported) -> None:
    """The chosen model refitted with every normal tilted `NORMAL_TILT_DEG` toward and away
    from the optical axis, and the offset's change between them (half their difference per
    axis): the uncertainty an error the frames share gives it, which neither the standard
    error nor the halves see (`offset_halves`). For a reconstructed shape.

    Measured on that capture (light at (4, -3, 0) mm): the offset 0.81 mm off the truth,
    (0.13, -0.25, 0.76) mm, with standard errors (0.04, 0.04, 0.09) and halves (0.02, 0.11,
    0.14); the same shape with the true normals puts it 0.19 mm off, with the true depth and
    the reconstructed normals 0.83 mm: the normals are what puts it off. This check gives
    (0.22, 0.37, 0.16) mm there (0.46 in all). On four more reconstructed captures (the
    same after `reconstruct --shading near`; 8 frames, seeds 1-3) the offset is 0.42, 0.08,
    0.20 and 0.50 mm off and the check gives 0.48, 0.74, 0.50 and 0.41 mm: of the error's
    size, where the standard errors are 0.02-0.09 mm, but not a bound (the 5 frames' 0.76
    mm along the axis against 0.16). A warning says so where the change is more than
    `HALVES_BEYOND_NOISE` times the standard error. Two refits more."""
    tilted = [tilted_normals(tracks, d) for d in (NORMAL_TILT_DEG, -NORMAL_TILT_DEG)]
    refitted = _refitted_offsets(result, fit, tilted)
    if refitted is None:
        return
    _, change = refitted
    result.details["offset_normal_tilt_deg"] = NORMAL_TILT_DEG
    result.details["offset_per_normal_tilt_mm"] = change.tolist()
    _beyond_noise(
        result,
        change,
        reported,
        f"when every normal is tilted {NORMAL_TILT_DEG:g} degrees toward or away from the "
        "optical axis (a reconstruction's normals are about that far off, and every frame's "
        "alike where its smoothing flattens the surface)",
        ": the shape, not the image noise, bounds where the light is (refining it by the "
        "shading, reconstruct --shading near, helps)",
    )


def _refitted_offsets(result, fit, variants):
    """The chosen model refitted on each of the two `variants` of its tracks: their offsets
    and half their difference per axis, or None where a refit is not finite."""
    offsets = []
    for tracks in variants:
        estimate = fit([result.model], tracks)
        if not np.isfinite(estimate.cost):
            return None
        offsets.append(np.asarray(estimate.model.light.position_mm, float))
    return offsets, np.abs(offsets[0] - offsets[1]) / 2


def _beyond_noise(result, change, reported, how: str, then: str) -> None:
    """A warning where the offset's `change` (per axis, moved `how`) is more than
    `HALVES_BEYOND_NOISE` times its standard error (`reported`), ending with `then`."""
    noise = np.asarray([np.nan if e is None else e for e in reported], float)
    if np.any(change > HALVES_BEYOND_NOISE * noise):
        unit = label(result.details["length_unit"])
        result.warnings.append(
            f"the light's offset moves by {_two_figures(change)} {unit} {how}, more "
            f"than {HALVES_BEYOND_NOISE:g} times its standard error "
            f"{_two_figures(noise)} {unit}{then}"
        )


def _two_figures(values) -> str:
    """Per axis, to two significant figures: a standard error of 0.003 median depths is not
    shown as 0.0 beside an offset change of 0.01."""
    return "[" + ", ".join(f"{float(v):.2g}" for v in np.ravel(values)) + "]"
