"""How much lens distortion do a capture's own frames show? SfM with the pinhole camera (as
`ctjax reconstruct --focal refine` runs it), then one bundle adjustment with OpenCV's
distortion model (k1, k2, p1, p2) and the focal lengths free, the principal point held.

    python benchmarks/lens_distortion.py CAPTURE

Prints the pinhole and the distorted camera's parameters, the reprojection errors, and the
radial factor 1 + k1 r^2 + k2 r^4 at the image's half-width and corner. A camera guessed
for a video (`ctjax import --camera guess`) has none; if the frames asked for much, the
monocular shape's orientation could be off by it (`benchmarks/highlight_normals.py`).
Mapping with the distortion free from the start does not work on 12 frames: on the
cholecystectomy video SIMPLE_RADIAL and RADIAL registered 2 of 12 frames with k1 of 61 and
2.7. Measured (2026-11-28, the cholecystectomy video, 12 frames at 640x360, `ctjax import
--camera guess`): pinhole 372.9 / 370.0 px, 0.983 px; with distortion 357.9 / 355.8 px,
k1 -0.047, k2 0.047, p1 -0.005, p2 -0.006, 0.975 px: the radial factor within 1% of 1 over
the image, far too little to tilt the shape by tens of degrees.
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np
import pycolmap
from _results import emit

from ctjax.io import load_capture
from ctjax.sfm import _colmap


def lens_distortion(root: Path) -> dict:
    capture = load_capture(root)
    camera = capture.camera
    frames = sorted(capture.frames, key=lambda f: f.name)
    with tempfile.TemporaryDirectory(prefix="ctjax-distortion-") as tmp:
        folder = Path(tmp)
        _colmap._write_workspace(folder, frames, 1)
        _colmap._extract_features(folder, camera, 0.002, 16384)
        _colmap._match(folder / "database.db", "exhaustive", 0)
        options = _colmap._mapping_options(0, 4.0, refine_focal=True)
        models = pycolmap.incremental_mapping(
            folder / "database.db", folder / "images", folder / "sparse", options=options
        )
    if not models:
        return {"capture": str(root), "registered": 0}
    model = max(models.values(), key=lambda m: m.num_reg_images())
    (camera_id, pinhole), *_ = model.cameras.items()
    fx, fy, cx, cy = (float(x) for x in pinhole.params)
    before = float(model.compute_mean_reprojection_error())
    model.cameras[camera_id] = pycolmap.Camera(
        model="OPENCV",
        width=pinhole.width,
        height=pinhole.height,
        params=[fx, fy, cx, cy, 0.0, 0.0, 0.0, 0.0],
        camera_id=camera_id,
    )
    adjustment = pycolmap.BundleAdjustmentOptions()
    adjustment.refine_focal_length = True
    adjustment.refine_principal_point = False
    adjustment.refine_extra_params = True
    pycolmap.bundle_adjustment(model, adjustment)
    params = [float(x) for x in model.cameras[camera_id].params]
    k1, k2 = params[4], params[5]

    def factor(px):
        r2 = (px / params[0]) ** 2
        return 1 + k1 * r2 + k2 * r2**2

    return {
        "capture": str(root),
        "registered": int(model.num_reg_images()),
        "pinhole_fx_fy": [fx, fy],
        "pinhole_reprojection_px": before,
        "opencv_params": params,
        "opencv_reprojection_px": float(model.compute_mean_reprojection_error()),
        "radial_factor_half_width": factor(pinhole.width / 2),
        "radial_factor_corner": factor(float(np.hypot(pinhole.width, pinhole.height)) / 2),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    row = lens_distortion(parser.parse_args().capture)
    emit(row)
    if row["registered"]:
        k = ", ".join(f"{x:.4f}" for x in row["opencv_params"][4:])
        print(
            f"{row['registered']} frames; pinhole fx, fy {row['pinhole_fx_fy'][0]:.1f}, "
            f"{row['pinhole_fx_fy'][1]:.1f} px, {row['pinhole_reprojection_px']:.3f} px; OpenCV "
            f"fx, fy {row['opencv_params'][0]:.1f}, {row['opencv_params'][1]:.1f}, k1 k2 p1 p2 "
            f"{k}, {row['opencv_reprojection_px']:.3f} px; radial factor at the half-width "
            f"{row['radial_factor_half_width']:.4f}, at the corner "
            f"{row['radial_factor_corner']:.4f}"
        )


if __name__ == "__main__":
    main()
