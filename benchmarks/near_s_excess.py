"""Where the light the model lacks is: the held-out views' excess (measured - model) by their
distance to S and by the angle between the model's N and H.

    python benchmarks/near_s_excess.py CAPTURE [--calib N]

`ctjax evaluate --no-sfs`'s protocol (Lambert and Cook-Torrance with its near light fitted
on the calibration frames, every test view of a tracked point predicted from the point's
other views, `ctjax.heldout.HeldOutTracks`), then, for each model, the test views' mean
excess (8-bit levels, mean of the channels) in a table: rows by the distance (px) to S and,
separately, to the saturated pixels; columns by the angle between N and H. A lobe about the
model's normals puts its light where that angle is small: an excess near S that does not
fall with it is light those normals do not place. `evaluate` prints the angle split within
7 px of S (`highlight_excess_by_angle`); this prints the whole table.

Measured (2026-12-04, 07e5df3, `benchmarks/real_video.py` captures, 12 frames at 640 px):
the shared cholecystectomy, Cook-Torrance: the test views in S (4.0%) +45.8 levels, white
(R / G / B +47.2 / +44.2 / +45.9), +35 to +70 levels in every angle bin from 5 to 90
degrees; 1-3 px from S +0.7; 69% of the squared residual within 3 px of S; within 7 px of
the saturated pixels -4.5 to -5.5 (no glare around the cores). The shared sinus: 0.09% of
its test views within 7 px of S (its highlights clipped in red). SCARED frames 61-72 (da
Vinci, the paper's lobe found; `benchmarks/scared_capture.py`): Lambert's excess in S falls
with the angle, +24.3 at 0-5 degrees to +8.9 at 45-90. docs/real-video.md, "The excess near
S by the angle between N and H".
"""

import argparse
import itertools

import cv2
import jax
import numpy as np

DISTANCE_BINS_PX = (0, 1, 3, 7, 15, 30, 60, np.inf)
ANGLE_BINS_DEG = (0, 5, 10, 15, 20, 30, 45, 90)


def _views(tracks, model):
    """The judged test views of `model`: excess (N, 3), weight (N,), frame, row, col and the
    angle between N and H (degrees)."""
    from ctjax._vector import Vec3
    from ctjax.diagnostics import physical_variables
    from ctjax.fitting._map_least_squares import heldout_map_residuals
    from ctjax.observations import PixelSamples

    model = tracks.with_heldout_frames(model)
    test = tracks.test
    residual, weight = heldout_map_residuals(model, test, tracks.judged)
    kept = weight > 0
    m, p = kept.shape

    def at_views(leaf):  # a corner array (4, M, P): its bilinear mean per kept view
        return np.sum(np.asarray(test.corner_weight) * np.asarray(leaf).reshape(4, m, p), 0)[kept]

    point = np.stack([at_views(c) for c in (test.point.x, test.point.y, test.point.z)], -1)
    normal = np.stack([at_views(c) for c in (test.normal.x, test.normal.y, test.normal.z)], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    u, v = (np.asarray(a)[kept] for a in test.site.pixel)
    frame = np.asarray(test.site.frame)[kept]
    row, col = np.rint(v).astype(int), np.rint(u).astype(int)
    samples = PixelSamples(
        Vec3.from_array(point),
        Vec3.from_array(normal),
        (u, v),
        np.asarray(test.values)[:, kept].T,
        frame,
        row,
        col,
    )
    angle = np.asarray(physical_variables(model, samples, tracks.capture.camera)["angle_n_h_deg"])
    return residual[:, kept].T, weight[kept], frame, row, col, angle


def _distances(observations, frame, row, col):
    """Each view's distance (px) to S and to the saturated pixels of its frame."""
    camera = observations.capture.camera
    row, col = np.clip(row, 0, camera.height - 1), np.clip(col, 0, camera.width - 1)
    to_s, to_saturated = np.full(len(frame), np.inf), np.full(len(frame), np.inf)
    for index in np.unique(frame):
        here = frame == index
        to_s[here] = observations.specular_distance(int(index))[row[here], col[here]]
        saturated = observations.sets[index].saturated
        if saturated.any():
            distance = cv2.distanceTransform((~saturated).astype(np.uint8), cv2.DIST_L2, 5)
            to_saturated[here] = distance[row[here], col[here]]
    return to_s, to_saturated


def _cell(excess, weight, where, total) -> str:
    if weight[where].sum() <= 5e-4 * total:
        return "-"
    mean = np.sum(weight[where] * excess[where]) / weight[where].sum()
    return f"{mean:+.1f} ({100 * weight[where].sum() / total:.0f}%)"


def _table(title, distance, angle, excess, weight) -> None:
    total = weight.sum()
    angles = list(itertools.pairwise(ANGLE_BINS_DEG))
    print(f"  by the distance to {title} (px; rows) and the angle between N and H (deg)")
    print("  " + "".ljust(9) + "".join(f"{a}-{b}".rjust(13) for a, b in angles) + "all".rjust(13))
    for low, high in itertools.pairwise(DISTANCE_BINS_PX):
        band = (distance >= low) & (distance < high)
        cells = [_cell(excess, weight, band & (angle >= a) & (angle < b), total) for a, b in angles]
        cells.append(_cell(excess, weight, band, total))
        print("  " + f"{low:g}-{high:g}".ljust(9) + "".join(c.rjust(13) for c in cells))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture")
    parser.add_argument("--calib", type=int, default=None)
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    from ctjax._performance import enable_compilation_cache
    from ctjax.evaluation import evaluate
    from ctjax.heldout import HeldOutTracks
    from ctjax.io import load_capture
    from ctjax.observations import Observations

    enable_compilation_cache()
    observations = Observations.of(load_capture(args.capture))
    evaluation = evaluate(observations.capture, calibration=args.calib, sfs=False)
    tracks = HeldOutTracks.split(observations, len(evaluation.calibration_frames))
    models = {"Lambert under the same light": evaluation.lambertian_same_light}
    models["Cook-Torrance"] = evaluation.cook_torrance
    for name, estimate in models.items():
        if estimate is None:
            continue
        residual, weight, frame, row, col, angle = _views(tracks, estimate.model)
        excess = residual.mean(axis=1)
        rmse = np.sqrt(np.sum(weight * np.mean(residual**2, axis=1)) / weight.sum())
        print(f"\n{name}: {len(weight)} test views, RMSE {rmse:.2f} levels; mean measured - model")
        to_s, to_saturated = _distances(observations, frame, row, col)
        in_s = to_s == 0
        if in_s.any():
            channels = np.sum(weight[in_s, None] * residual[in_s], 0) / weight[in_s].sum()
            print(
                f"  in S: {100 * weight[in_s].sum() / weight.sum():.1f}% of the views, "
                f"R / G / B {' / '.join(f'{c:+.1f}' for c in channels)} levels"
            )
        _table("S", to_s, angle, excess, weight)
        _table("the saturated pixels", to_saturated, angle, excess, weight)
        squared = weight * np.mean(residual**2, axis=1)
        near = {f"{d} px": np.sum(squared[to_s <= d]) / squared.sum() for d in (3, 7)}
        print(
            "  share of the squared residual within "
            + ", ".join(f"{d} of S {100 * s:.0f}%" for d, s in near.items())
        )


if __name__ == "__main__":
    main()
