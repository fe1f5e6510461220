"""`ctjax reconstruct`: the shape of the organ from images alone (paper section 6, step 1).

Sparse rigid SfM (pycolmap, `_colmap.py`), then a dense smooth surface per registered view
fitted to the points of all frames at once (`_surface.py`) and refined by the texture's
consistency between frames at every pixel (`_photometric.py`), giving depth and normals at
every pixel inside the convex hull of the points' projections, and the poses.

World frame of the output: the camera frame of the reference view (the first registered
frame), so its pose is the identity. Length unit: SfM recovers shape up to scale; with
`scale_mm` or `volume_mm3` the output is in mm, otherwise the unit is the median depth of the
reference view (its median depth is 1) and the report says so.
"""

import dataclasses
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from .._camera import Camera
from .._errors import CaptureError, CtjaxError, ParameterError, ReconstructionError
from .._units import unit_of_reconstruction
from ..io import Capture, load_capture
from ..io._atomic import atomic_write_json, atomic_write_npy
from ..io._camera_json import AUTO_CEILINGS, read_ceilings
from ..io._excluded import EXCLUDED
from ._agreement import refinement_agreement
from ._checks import check_knots, check_scale
from ._colmap import MAPPING_ENOUGH, SparseModel
from ._focal import sparse_with_focal, with_focal
from ._pairs import pairs_reconstruction
from ._photometric import PARTNERS, SMOOTHING, photometric_report, refine_views
from ._report import reconstruction_report
from ._stereo import stereo_points, stereo_report, stereo_scale
from ._surface import DepthSurface, fit_depth_surface

# Fraction kept along each axis for the bounding box of `volume_mm3` (robust to stray points).
_BOX_PERCENTILES = (0.5, 99.5)


@dataclasses.dataclass(frozen=True)
class ViewSurface:
    """The reconstructed surface seen from one registered frame (camera frame, output unit)."""

    name: str
    surface: DepthSurface  # depth in the output unit (scale applied)
    hull: np.ndarray  # (H, W) bool: inside the convex hull of the points' projections
    pose: np.ndarray  # (4, 4) camera-to-world, world = reference camera frame
    points: int  # sparse points supporting the fit

    def depth_and_normals(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """float32 depth (H, W) and unit normals (H, W, 3) on the pixel grid; NaN outside."""
        v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
        depth, normals = self.surface.geometry(camera, u, v)
        depth[~self.hull] = np.nan
        normals[~self.hull] = np.nan
        return depth.astype(np.float32), normals.astype(np.float32)


@dataclasses.dataclass(frozen=True)
class Reconstruction:
    """Registered views' surfaces, the sparse model and the JSON-ready report."""

    camera: Camera
    views: dict[str, ViewSurface]
    sparse: SparseModel
    report: dict


def _to_camera(cam_from_world: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]


def _project(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = points[:, 2]
    u = float(camera.fx) * points[:, 0] / z + float(camera.cx)
    v = float(camera.fy) * points[:, 1] / z + float(camera.cy)
    return u, v


def _hull_mask(camera: Camera, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    mask = np.zeros((camera.height, camera.width), np.uint8)
    if len(u) >= 3:
        # Fixed-point polygon (4 fractional bits) so the hull is not rounded to whole pixels.
        shift = 4
        corners = np.round(np.stack([u, v], -1) * (1 << shift)).astype(np.int32)
        hull = cv2.convexHull(corners)
        cv2.fillConvexPoly(mask, hull, 1, lineType=cv2.LINE_8, shift=shift)
    return mask.astype(bool)


def reconstruct_capture(
    capture: Capture,
    *,
    scale_mm: float | None = None,
    volume_mm3: float | None = None,
    knot_spacing_px: float | None = None,
    photometric: bool = True,
    texture_smoothing: float | None = None,
    stereo: str = "scale",
    focal: str = "fixed",
    progress: Callable[[str], None] | None = None,
    verbose: bool = False,
) -> Reconstruction:
    """Rigid SfM and a dense surface per registered frame of a loaded (undistorted) capture.

    `scale_mm`: the median depth (camera-frame z, mm) of the reconstructed surface over the
    reference frame's covered pixels, i.e. the working distance of the first registered
    frame. `volume_mm3`: the volume of the axis-aligned bounding box (reference camera axes)
    of the sparse points, each axis trimmed to its 0.5-99.5 percentiles (the paper's known
    size). Without either, depth is up to scale (median reference depth = 1).

    `stereo`: on a stereo capture (camera.json's "stereo", right/NAME.png), what the pairs'
    depth (`_stereo.py`) is used for: `"scale"` (default) SfM's scale (mm, unless
    `scale_mm` or `volume_mm3` says otherwise), `"surface"` also their dense points for
    every view's surface beside SfM's, `"none"` nothing, `"pairs"` everything: no SfM,
    each frame's surface from its own pair and its pose by PnP (`_pairs.py`: a scope held
    still gives SfM no parallax).

    `photometric`: refine each view's surface by the texture seen from the other frames
    (`_photometric.py`; on by default: SfM's points alone leave the normals 2-3 degrees off
    where the BRDF is measured). `texture_smoothing`: its thin-plate penalty weight relative
    to the data's (default `_photometric.SMOOTHING`; docs: reconstruct, what 2 changes).

    `focal`: `"fixed"` (the camera's, default) or `"refine"`: refined by bundle adjustment
    from two starts and kept where they agree (`_focal.py`; an uncalibrated video's guessed
    camera); the report's `focal` says which, and `Reconstruction.camera` is the one used.

    Raises `ReconstructionError` (too few features, no initial pair); frames that do not
    register are listed in the report and get no geometry.
    """
    check_scale(scale_mm, volume_mm3, knot_spacing_px, texture_smoothing)
    if knot_spacing_px is not None:
        check_knots(capture.camera, knot_spacing_px)
    if texture_smoothing is not None and (not photometric or stereo == "pairs"):
        raise ParameterError(
            "texture_smoothing (--texture-smoothing) is the texture refinement's: not with "
            + ("photometric=False (--no-photometric)" if not photometric else "--stereo pairs")
        )
    smoothing = SMOOTHING if texture_smoothing is None else float(texture_smoothing)
    say = progress or (lambda message: None)
    if stereo == "pairs":  # no SfM: each frame's pair, poses by PnP (`_pairs.py`)
        if focal != "fixed" or scale_mm is not None or volume_mm3 is not None:
            raise ParameterError("--stereo pairs is in mm with the given camera: no scale, focal")
        knot = max(capture.camera.width, capture.camera.height) / 20
        found, report = pairs_reconstruction(capture, knot_spacing_px or knot, say)
        views = {name: ViewSurface(name, *parts) for name, parts in found.items()}
        return Reconstruction(capture.camera, views, None, report)
    # A stereo capture still has its pairs: metric depth at every instant, whatever the
    # scope's motion. Held (nearly) still, SfM finds no pair of frames with parallax, or
    # registers a few frames on a baseline too short for their surfaces (the SurgT da Vinci
    # clip: 3 of 10 frames, no surface, 65 s): the pairs then reconstruct it instead.
    pairs_possible = (
        capture.stereo is not None
        and stereo in ("scale", "surface")
        and focal == "fixed"
        and scale_mm is None
        and volume_mm3 is None
    )
    try:
        sparse, camera, focal_report = sparse_with_focal(capture, focal, progress, verbose)
    except ReconstructionError as error:
        if not pairs_possible:
            raise
        return _pairs_instead(capture, error, knot_spacing_px, texture_smoothing, progress)
    if pairs_possible and len(sparse.registered) < MAPPING_ENOUGH * len(capture.frames):
        error = ReconstructionError(
            f"structure-from-motion registered {len(sparse.registered)} of "
            f"{len(capture.frames)} frames (too little parallax: a scope held nearly still?)"
        )
        return _pairs_instead(capture, error, knot_spacing_px, texture_smoothing, progress)
    reference = sparse.registered[0]
    ref_from_world = sparse.cam_from_world[reference]
    points = _to_camera(ref_from_world, sparse.points)
    # Unit: median depth of the points in front of the reference view = 1 (well-conditioned).
    in_front = points[:, 2] > 0
    unit = float(np.median(points[in_front, 2])) if in_front.any() else 1.0
    points = points / unit
    world_from_ref = np.linalg.inv(ref_from_world)
    if knot_spacing_px is None:
        knot_spacing_px = max(camera.width, camera.height) / 20

    surfaces, hulls, counts, cams = _view_surfaces(
        camera, sparse, points, world_from_ref, unit, knot_spacing_px, say
    )
    if not surfaces and not pairs_possible:  # (12 frames of a video over 1.5 s: 11 points)
        raise ReconstructionError(
            f"structure-from-motion's {len(sparse.points)} points from "
            f"{len(sparse.registered)} frames give no frame a surface (at least 16 points in "
            "view needed): too little texture or parallax between the frames (frames further "
            "apart in time move the camera more)"
        )
    if pairs_possible and reference not in surfaces:
        error = ReconstructionError(
            f"structure-from-motion's points give its first frame ({reference}) no surface "
            f"({len(sparse.points)} points from {len(sparse.registered)} frames)"
        )
        return _pairs_instead(capture, error, knot_spacing_px, texture_smoothing, progress)
    scale, scale_info = _scale(camera, surfaces.get(reference), hulls.get(reference), points)
    pairs = {}
    if stereo not in STEREO_USES:
        raise ParameterError(f"stereo must be one of {STEREO_USES}, got {stereo!r}")
    if capture.stereo is not None and stereo != "none":
        index = {frame.name: i for i, frame in enumerate(capture.frames)}
        pairs = {name: stereo_points(capture, index[name]) for name in surfaces}
        say(f"stereo: {sum(map(len, pairs.values()))} points from {len(pairs)} pairs")
        if scale_mm is None and volume_mm3 is None:
            scale = stereo_scale(surfaces, hulls, pairs, scale_info, capture.stereo)
    if scale_mm is not None:
        scale = scale_mm / scale_info["median_reference_depth"]
        scale_info.update(metric=True, method="scale_mm", value=scale_mm)
    elif volume_mm3 is not None:
        scale = (volume_mm3 / scale_info["bounding_box_volume"]) ** (1 / 3)
        scale_info.update(metric=True, method="volume_mm3", value=volume_mm3)
    scale_info["factor"] = scale
    scale_info["unit"] = "mm" if scale_info["metric"] else "median reference depth (up to scale)"

    views = {}
    for name, surface in surfaces.items():
        pose = np.linalg.inv(cams[name])
        pose[:3, 3] *= scale
        u, v, z, weight = surface.points
        if name in pairs and stereo == "surface":  # SfM's points and the pair's (mm)
            pair = pairs[name]
            u, v, z = (np.concatenate(a) for a in ((u, pair.u), (v, pair.v), (z * scale, pair.z)))
            margin = knot_spacing_px  # as `_view_surfaces`
            bounds = (-margin, camera.width - 1 + margin, -margin, camera.height - 1 + margin)
            scaled = fit_depth_surface(u, v, z, bounds, knot_spacing_px=knot_spacing_px)
            hull = _hull_mask(camera, u[scaled.inliers], v[scaled.inliers])
            views[name] = ViewSurface(name, scaled, hull, pose, int(scaled.inliers.sum()))
            continue
        scaled = dataclasses.replace(
            surface,
            coefficients=surface.coefficients * scale,
            residual_rms=surface.residual_rms * scale,
            points=(u, v, z * scale, weight),
        )
        views[name] = ViewSurface(name, scaled, hulls[name], pose, counts[name])
    refinements = agreement = None
    if photometric and len(views) > 1:
        refined, refinements = refine_views(camera, views, capture.frames, say, smoothing)
        # Kept only where the frames' surfaces still agree (`_agreement.py`).
        agreement = refinement_agreement(camera, views, refined, PARTNERS)
        if agreement["kept"]:
            views = refined
        else:
            say(
                f"texture refinement not kept: the frames' surfaces agree within 1% at "
                f"{agreement['refined']:.2f} of their points, {agreement['sfm']:.2f} without it"
            )

    report = reconstruction_report(
        sparse, views, reference, points, scale_info, counts, knot_spacing_px
    )
    if pairs:
        report["stereo"] = stereo_report(pairs, capture.stereo, stereo)
    report["surface"]["photometric"] = photometric_report(refinements, smoothing, agreement)
    report["focal"] = focal_report
    return Reconstruction(camera, views, sparse, report)


STEREO_USES = ("scale", "surface", "none", "pairs")


def _pairs_instead(capture, error, knot_spacing_px, texture_smoothing, progress):
    """`--stereo pairs` where structure-from-motion failed on a stereo capture, with the
    reason in the report (`sfm_failed`) and its first warning."""
    say = progress or (lambda message: None)
    say(f"{error}: each frame's depth from its own stereo pair instead (--stereo pairs)")
    try:
        result = reconstruct_capture(
            capture, stereo="pairs", knot_spacing_px=knot_spacing_px, progress=progress
        )
    except CtjaxError as second:
        raise ReconstructionError(f"{error}; from the stereo pairs alone: {second}") from second
    warnings = [
        f"{error}: each frame's depth and normals come from its own stereo pair instead, its "
        "pose by PnP (--stereo pairs; noisier normals than SfM's)"
    ]
    if texture_smoothing is not None:
        warnings.append("--texture-smoothing not applied: no texture refinement with the pairs")
    result.report["sfm_failed"] = str(error)
    result.report["warnings"][:0] = warnings
    return result


def _scale(camera, surface, hull, points):
    """Sizes of the unscaled reconstruction that `scale_mm` and `volume_mm3` refer to."""
    median = float("nan")
    if surface is not None and hull is not None and hull.any():
        rows, cols = np.nonzero(hull)
        depth, _ = surface.depth_and_gradient(cols.astype(float), rows.astype(float))[:2]
        median = float(np.nanmedian(depth))
    lo, hi = np.percentile(points, _BOX_PERCENTILES, axis=0)
    volume = float(np.prod(hi - lo))
    return 1.0, {
        "metric": False,
        "method": "none",
        "median_reference_depth": median,
        "bounding_box_volume": volume,
        "definition": {
            "scale_mm": "median depth (camera-frame z) of the reference frame's surface",
            "volume_mm3": "volume of the sparse points' bounding box in reference camera "
            "axes, each axis trimmed to its 0.5-99.5 percentiles",
        },
    }


def _geometry_files(out: Path, names) -> list[Path]:
    files = [out / "poses.json", out / "reconstruction.json"]
    for name in names:
        files += [out / "depth" / f"{name}.npy", out / "normals" / f"{name}.npy"]
    return files


def reconstruct(
    capture_dir: str | Path,
    out: str | Path | None = None,
    *,
    scale_mm: float | None = None,
    volume_mm3: float | None = None,
    force: bool = False,
    photometric: bool = True,
    texture_smoothing: float | None = None,
    shading: bool | str = False,
    stereo: str = "scale",
    focal: str = "fixed",
    knot_spacing_px: float | None = None,
    progress: Callable[[str], None] | None = None,
    verbose: bool = False,
) -> dict:
    """Reconstruct a capture's shape from its images and write it in the capture format.

    Writes `depth/NAME.npy`, `normals/NAME.npy` (registered frames), `poses.json`
    (camera-to-world, world = the reference camera frame) and `reconstruction.json` (the
    report) into `out` (default: the capture folder). A different `out` becomes a complete
    capture: camera.json, images/ (and truth.json if any) are copied. Existing files are
    never overwritten unless `force=True` (else `CaptureError` naming the file). With a
    distorted camera, depth and normals are evaluated at the undistorted position of every
    pixel, so that `load_capture` (which undistorts them) reads them back on its grid.
    `shading`: then refine the shape by the shading of every frame, one world surface fitted
    with the BRDF (`_shading.py`): True or "camera" with the paper's light, at the camera;
    "near" jointly with a point light's offset in the lens plane (inverse-square falloff,
    from the lens: `SHADING_LIGHTS`); the report's `surface.shading` says what it did (with
    "near", the light's fitted `position_mm` in the capture's length unit), or why it was
    skipped. `stereo`: see
    `reconstruct_capture` (a stereo capture is in mm without a size given). `focal`: see
    `reconstruct_capture`; a refined focal length is written into `out`'s camera.json (in
    place only with `force`), the given one kept in the report. `knot_spacing_px`: the dense
    surfaces' knot spacing (default: a twentieth of the image's larger side), the scale of
    the relief their normals resolve. `texture_smoothing`: see `reconstruct_capture`.

    Returns the report (see `reconstruct_capture`).
    """
    check_scale(scale_mm, volume_mm3, knot_spacing_px, texture_smoothing)
    if shading not in (None, False, True, *SHADING_LIGHTS):
        raise CaptureError(f"shading must be one of {', '.join(SHADING_LIGHTS)}, got {shading!r}")
    root = Path(capture_dir)
    capture = load_capture(root, reconstructed_ceilings=False)  # found on these frames
    out = root if out is None else Path(out)
    names = [f.name for f in capture.frames]
    copies = []
    if out.resolve() != root.resolve():
        image_files = sorted(p for p in (root / "images").iterdir() if p.is_file())
        copies = [root / "camera.json", *image_files]
        # A stereo capture's right images; the pixels excluded (instruments), of either.
        for folder in ("right", EXCLUDED, f"{EXCLUDED}/right"):
            if (root / folder).is_dir():
                copies += sorted(p for p in (root / folder).iterdir() if p.is_file())
        if (root / "truth.json").is_file():
            copies.append(root / "truth.json")
        copies += sorted(p for p in root.glob(f"{EXCLUDED}.*") if p.is_file())  # every frame's
    targets = [out / p.relative_to(root) for p in copies] + _geometry_files(out, names)
    if focal == "refine" and not copies:  # in place: the refined focal length goes there
        targets.append(out / "camera.json")
    if not force:
        for target in targets:
            if target.exists():
                raise CaptureError(f"{target}: exists; not overwriting it (--force replaces it)")
    result = reconstruct_capture(
        capture,
        scale_mm=scale_mm,
        volume_mm3=volume_mm3,
        photometric=photometric,
        texture_smoothing=texture_smoothing,
        stereo=stereo,
        focal=focal,
        knot_spacing_px=knot_spacing_px,
        progress=progress,
        verbose=verbose,
    )
    for source in copies:
        target = out / source.relative_to(root)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)
    if result.report["focal"]["status"] == "refined":
        camera_json = json.loads((root / "camera.json").read_text())
        atomic_write_json(out / "camera.json", with_focal(camera_json, result.report["focal"]))
    distorted = _distorted_pixels(root, capture.camera)
    for name in names:
        view = result.views.get(name)
        depth_path, normals_path = out / "depth" / f"{name}.npy", out / "normals" / f"{name}.npy"
        if view is None:
            # A stale map of a frame that no longer registers would contradict the new poses.
            depth_path.unlink(missing_ok=True)
            normals_path.unlink(missing_ok=True)
            continue
        if distorted is None:
            depth, normals = view.depth_and_normals(result.camera)
        else:
            depth, normals = _on_distorted_grid(view, capture.camera, *distorted)
        atomic_write_npy(depth_path, depth)
        atomic_write_npy(normals_path, normals)
    poses = {name: view.pose.tolist() for name, view in result.views.items()}
    atomic_write_json(out / "poses.json", poses)
    report = {**result.report, "capture": str(root), "out": str(out)}
    report |= {"encoding": capture.encoding, "notes": list(capture.notes)}
    if read_ceilings(root / "camera.json") == AUTO_CEILINGS:
        # What every frame showed, for a subset of them to read as the whole (`load_capture`):
        # a second sinus video's red ceiling at 211 was found on 12 frames and missed on their
        # even and odd six, whose RMSE doubled (docs/real-video.md).
        report["ceilings"] = [None if c is None else int(c) for c in capture.ceilings]
    if shading:
        report["surface"]["shading"] = _refine_by_shading(
            out, distorted is not None, progress, "camera" if shading is True else shading
        )
    atomic_write_json(out / "reconstruction.json", report)
    return report


# The lights `reconstruct(shading=...)` refines the shape under (the command line's
# `--shading LIGHT`).
SHADING_LIGHTS = ("camera", "near")


def _shading_light(name: str, capture: Capture):
    """The light the shading refinement starts from: the paper's (held), or a point light at
    the lens with inverse-square falloff at the working distance, its offset fitted in the
    lens plane (`LensPlaneLight`, as calibrate-light fits it by default)."""
    import jax.numpy as jnp

    from ..lights import InverseSquare, LensPlaneLight

    if name not in SHADING_LIGHTS:
        raise CaptureError(f"shading must be one of {', '.join(SHADING_LIGHTS)}, got {name!r}")
    if name == "camera":
        return None
    depth = np.concatenate([f.depth[np.isfinite(f.depth)] for f in capture.frames])
    reference = float(np.median(depth))
    return LensPlaneLight(jnp.zeros(2), falloff=(InverseSquare(reference),))


def _refine_by_shading(out: Path, distorted: bool, progress, light: str = "camera") -> dict:
    """Refine the written shape by the shading (`_shading.py`) under `light`
    (`SHADING_LIGHTS`) and write it back; the refinement's report, or why it was skipped."""
    from .._errors import CtjaxError
    from ._shading import refine_shape_by_shading

    if distorted:
        return {"refined": False, "reason": "a distorted camera (not supported yet)"}
    say = progress or (lambda message: None)
    try:
        capture = load_capture(out)
        start = _shading_light(light, capture)
        refined, report = refine_shape_by_shading(capture, light=start, say=say)
    except CtjaxError as error:
        return {"refined": False, "reason": str(error)}
    if "rejected" in report:
        return {"refined": False, "reason": report["rejected"], **report}
    for frame in refined.frames:
        atomic_write_npy(out / "depth" / f"{frame.name}.npy", frame.depth.astype(np.float32))
        atomic_write_npy(out / "normals" / f"{frame.name}.npy", frame.normals.astype(np.float32))
    return {"refined": True, **report}


def _distorted_pixels(root: Path, camera: Camera):
    """Undistorted positions (u, v) of the pixels of a distorted camera, or None."""
    from ..io import read_camera

    raw = read_camera(root / "camera.json")
    if raw.distortion is None:
        return None
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    k = np.asarray(raw.intrinsic_matrix, np.float64)
    pixels = np.stack([u.ravel(), v.ravel()], -1)[:, None, :]
    ideal = cv2.undistortPoints(pixels, k, np.asarray(raw.distortion, np.float64), P=k)
    return ideal[:, 0, 0].reshape(u.shape), ideal[:, 0, 1].reshape(u.shape)


def _on_distorted_grid(view: ViewSurface, camera: Camera, u: np.ndarray, v: np.ndarray):
    depth, normals = view.surface.geometry(camera, u, v)
    rows = np.clip(np.round(v).astype(int), 0, camera.height - 1)
    cols = np.clip(np.round(u).astype(int), 0, camera.width - 1)
    outside = ~view.hull[rows, cols] | (u < -0.5) | (u > camera.width - 0.5)
    outside |= (v < -0.5) | (v > camera.height - 0.5)
    depth[outside] = np.nan
    normals[outside] = np.nan
    return depth.astype(np.float32), normals.astype(np.float32)


def with_reconstructed_shape(
    capture: Capture,
    *,
    shading: bool = False,
    progress: Callable[[str], None] | None = None,
) -> tuple[Capture, dict]:
    """The capture with SfM depth, normals and poses in memory (nothing is written).

    For commands that need the shape of a capture that has only images (`ctjax fit`).
    Frames that do not register are dropped (listed in the report's `unregistered`). Depth
    is up to scale (`length_unit` "median_depth"): the BRDF fit uses the normals and the
    view directions, which do not depend on it. `shading`: then refine the shape by the
    shading (`_shading.py`, the paper's light); the report's `surface.shading` says what it
    did, or why it was skipped.
    """
    from .._errors import CtjaxError
    from ._shading import refine_shape_by_shading

    result = reconstruct_capture(capture, progress=progress)
    frames = []
    for frame in capture.frames:
        view = result.views.get(frame.name)
        if view is not None:
            depth, normals = view.depth_and_normals(capture.camera)
            frames.append(dataclasses.replace(frame, depth=depth, normals=normals, pose=view.pose))
    unit = unit_of_reconstruction(result.report)
    capture = dataclasses.replace(capture, frames=tuple(frames), length_unit=unit)
    report = result.report
    if shading:
        try:
            capture, refined = refine_shape_by_shading(capture, say=progress or (lambda m: None))
            if "rejected" in refined:
                raise CtjaxError(refined["rejected"])
            report["surface"]["shading"] = {"refined": True, **refined}
        except CtjaxError as error:
            report["surface"]["shading"] = {"refined": False, "reason": str(error)}
            report["warnings"].append(f"no shading refinement: {error}")
    return capture, report


def _view_surfaces(camera, sparse, points, world_from_ref, unit, knot_spacing_px, say):
    """A depth surface per registered frame from the points it sees (with a margin of one
    knot spacing around the image): (surfaces, hulls, inlier counts, cam_from_ref)."""
    margin = knot_spacing_px
    surfaces, hulls, counts, cams = {}, {}, {}, {}
    for name in sparse.registered:
        cam_from_ref = sparse.cam_from_world[name] @ world_from_ref
        cam_from_ref[:3, 3] /= unit
        local = _to_camera(cam_from_ref, points)
        front = local[:, 2] > 1e-6
        u, v = _project(camera, local[front])
        inside = (
            (u >= -margin)
            & (u <= camera.width - 1 + margin)
            & (v >= -margin)
            & (v <= camera.height - 1 + margin)
        )
        u, v, z = u[inside], v[inside], local[front][inside, 2]
        if len(z) < 16:
            continue
        say(f"surface of {name} from {len(z)} points")
        surface = fit_depth_surface(
            u,
            v,
            z,
            (-margin, camera.width - 1 + margin, -margin, camera.height - 1 + margin),
            knot_spacing_px=knot_spacing_px,
        )
        surfaces[name] = surface
        hulls[name] = _hull_mask(camera, u[surface.inliers], v[surface.inliers])
        counts[name] = int(surface.inliers.sum())
        cams[name] = cam_from_ref

    return surfaces, hulls, counts, cams
