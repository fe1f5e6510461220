"""Do the frames' surfaces agree? The share of each view's surface points that the nearest
other views' surfaces place at the same depth.

A rigid scene has one surface: each frame's depth, carried into another frame by the poses,
lands on that frame's. The tracks (`ctjax._tracks`) follow a surface point into a frame
only where the two agree within `DEFAULT_TOLERANCE` (1% of the depth), so where the
frames' surfaces disagree the estimators lose views, and a point's normal differs from
frame to frame. `ctjax reconstruct` keeps its texture refinement only where it does not
cost that agreement (`refinement_agreement`).

Measured (docs: real video, 2026-12-03): on four stretches of the shared sinus and
cholecystectomy videos, the texture refinement, kept by its own loss in 6-16 frames of 12-16
(0.1-3.4% lower, moving the median depth by 0.7-7%), took the share within 1% from 0.43 to
0.29, 0.44 to 0.31, 0.86 to 0.69 and 0.91 to 0.68; the tracks then followed the same
points in 21-59% fewer views and the frames' normals of one point disagreed by 0.3-3.0
degrees more. On the synthetic 320x256 x 5 captures it refines (normals 2x nearer the
truth) the share stays at 0.999-1.000. Lambert's prediction of each real frame from the
others, on the pixels both surfaces cover, does not choose: two stretches favour the
refined surfaces, two SfM's, within 8%.
"""

import numpy as np

from .._camera import Camera
from .._tracks import DEFAULT_TOLERANCE

# Every this many pixels of a view's hull, in both directions.
STEP_PX = 8
# The refinement is kept unless it lowers the share by more than this (absolute): on the
# synthetic captures it moves the share by 0.001, on real video by 0.13-0.23.
MAX_AGREEMENT_LOSS = 0.02


def frames_agreement(
    camera: Camera, views: dict, partners: int, tolerance: float = DEFAULT_TOLERANCE
) -> float:
    """The share (0-1) of the views' surface points (every `STEP_PX`-th pixel of each
    view's hull) that each of the `partners` nearest other views (by camera position) places
    within `tolerance` of their depth, over the points that land inside that view's hull;
    NaN where none lands in another view. `views`: name -> `ViewSurface` (camera-to-world
    poses)."""
    centres = {name: view.pose[:3, 3] for name, view in views.items()}
    fx, fy, cx, cy = (float(x) for x in (camera.fx, camera.fy, camera.cx, camera.cy))
    agree = total = 0
    for name, view in views.items():
        rows, cols = np.nonzero(view.hull[::STEP_PX, ::STEP_PX])
        u, v = (cols * STEP_PX).astype(np.float64), (rows * STEP_PX).astype(np.float64)
        z = view.surface.depth_and_gradient(u, v)[0]
        point = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], -1)[z > 0]
        world = point @ view.pose[:3, :3].T + view.pose[:3, 3]
        others = sorted(
            (n for n in views if n != name),
            key=lambda n: float(np.linalg.norm(centres[n] - centres[name])),
        )[:partners]
        for other in others:
            to_other = np.linalg.inv(views[other].pose)
            local = world @ to_other[:3, :3].T + to_other[:3, 3]
            depth = local[:, 2]
            with np.errstate(invalid="ignore", divide="ignore"):
                uo, vo = fx * local[:, 0] / depth + cx, fy * local[:, 1] / depth + cy
            inside = (
                (depth > 0) & (uo >= 0) & (vo >= 0)
                & (uo <= camera.width - 1) & (vo <= camera.height - 1)
            )  # fmt: skip
            uo, vo, depth = uo[inside], vo[inside], depth[inside]
            inside_hull = views[other].hull[np.rint(vo).astype(int), np.rint(uo).astype(int)]
            uo, vo, depth = uo[inside_hull], vo[inside_hull], depth[inside_hull]
            there = views[other].surface.depth_and_gradient(uo, vo)[0]
            agree += int(np.sum(np.abs(there - depth) <= tolerance * depth))
            total += depth.size
    return agree / total if total else float("nan")


def refinement_agreement(camera: Camera, sfm: dict, refined: dict, partners: int) -> dict:
    """Whether the refined views (`refined`) keep the frames' agreement of the unrefined
    ones (`sfm`), for `reconstruct`'s report: the two shares, the tolerance and `kept`
    (False where the refinement lowers the share by more than `MAX_AGREEMENT_LOSS`)."""
    before = frames_agreement(camera, sfm, partners)
    after = frames_agreement(camera, refined, partners)
    kept = not after < before - MAX_AGREEMENT_LOSS  # NaN (no view overlaps): kept
    number = lambda x: float(x) if np.isfinite(x) else None  # noqa: E731
    return {
        "sfm": number(before),
        "refined": number(after),
        "tolerance": DEFAULT_TOLERANCE,
        "kept": kept,
        "note": "share of each frame's surface points (every "
        f"{STEP_PX}th pixel) that the {partners} nearest other frames' surfaces place within "
        "the tolerance (relative depth) of theirs, as the tracks follow a point; the texture "
        f"refinement is kept unless it lowers the share by more than {MAX_AGREEMENT_LOSS}",
    }
