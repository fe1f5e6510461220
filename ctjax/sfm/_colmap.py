"""Rigid structure-from-motion with pycolmap (paper section 6, step 1): sparse points and poses.

I/O at the edge: the (undistorted) frames are written to a scratch folder with masks that hide
the specular highlights from SIFT (a highlight moves with the light, i.e. with the camera: its
features match across views but not on the tissue, and would pull the poses and points off the
surface). COLMAP's intrinsics are the capture's, held fixed.

Pixel convention: ctjax puts the centre of pixel (i, j) at (u, v) = (j, i); COLMAP at
(j + 0.5, i + 0.5). The principal point is shifted by 0.5 on the way in, and keypoints by -0.5
on the way out.
"""

import contextlib
import dataclasses
import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from .._camera import Camera
from .._errors import ReconstructionError
from ..io import Frame
from ..specular import specular_sets

# Shorter sequences are matched exhaustively (every pair); longer ones as video, each frame
# with its `_SEQUENTIAL_OVERLAP` successors (COLMAP's quadratic overlap: the 1st, 2nd,
# 4th, ... next), and every pair after all where that registers too few frames. Measured
# on four real 24-frame captures at 640 px (one mapping run each): every pair registered
# 24/24 on all four (the cholecystectomy video over 8 and 10 s, the sinus, SCARED 61-84),
# the video order 3/24 and 2/24 on the cholecystectomy (4/24 and 3/24 after three seeds),
# with 22% and 43% more points on the sinus and SCARED, in 7.8 against 6.6 s, 22 against 13 s
# and 53 s either way.
EXHAUSTIVE_MAX_FRAMES = 40
_SEQUENTIAL_OVERLAP = 10
# A frame with fewer SIFT keypoints than this cannot be registered reliably.
MIN_KEYPOINTS = 100


@dataclasses.dataclass(frozen=True)
class SparseModel:
    """What SfM recovered: poses of the registered frames and the sparse 3D points.

    World frame: COLMAP's (arbitrary similarity). `cam_from_world[name]` maps world points
    into that frame's camera frame (x right, y down, z forward), 4x4.
    """

    names: tuple[str, ...]  # every frame, sorted
    registered: tuple[str, ...]
    cam_from_world: dict[str, np.ndarray]
    points: np.ndarray  # (N, 3) world
    point_errors: np.ndarray  # (N,) mean reprojection error, px
    track_lengths: np.ndarray  # (N,) number of frames observing each point
    keypoints: dict[str, int]  # SIFT keypoints per frame (after masking)
    matching: str  # "exhaustive", "sequential" or "sequential, then exhaustive"
    mean_reprojection_error: float
    # (fx, fy) in px after bundle adjustment: the given ones unless `refine_focal`.
    focal_px: tuple[float, float] | None = None

    @property
    def unregistered(self) -> tuple[str, ...]:
        return tuple(n for n in self.names if n not in self.registered)


def highlight_mask(image: np.ndarray, dilate_px: int) -> np.ndarray:
    """Pixels hidden from SIFT, dilated: the specular set S (highlights move with the
    light) and pixels with a clipped channel (a clipped channel bends the grey image's
    gradients: on the default demo, keeping pixels with one clipped channel raised the
    median normal error from 1.95 to 2.04 degrees, the 90th percentile from 4.4 to 4.8)."""
    sets = specular_sets(image)
    mask = (sets.specular | sets.saturated).astype(np.uint8)
    if dilate_px > 0 and mask.any():
        size = 2 * dilate_px + 1
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        mask = cv2.dilate(mask, kernel)
    return mask.astype(bool)


# The blur (px) whose removal from the log image leaves the texture SIFT looks at.
_DETAIL_BLUR_PX = 12.0
# 8-bit levels per unit of log intensity in the feature image.
_GAIN = 255.0


def _detail(image: np.ndarray) -> np.ndarray:
    """The log image less its blur: the texture, without the shading."""
    log = np.log(np.clip(np.asarray(image, np.float32), 1 / 255, None))
    return log - cv2.GaussianBlur(log, (0, 0), _DETAIL_BLUR_PX)


def texture_axis(frames, hidden) -> np.ndarray:
    """The colour axis along which the texture varies most (first principal component of
    the log images' detail over the unhidden pixels of all frames, sign fixed), (3,).

    SIFT reads grey images; tissue whose texture is mostly chromatic (vessels, bile) has
    little of it in the luminance: on an independent renderer's per-channel texture, SIFT
    on the grey image gave 155 SfM points at 640x512."""
    samples = []
    for frame, mask in zip(frames, hidden, strict=True):
        detail = _detail(frame.image)[~mask]
        samples.append(detail[:: max(1, len(detail) // 20_000)])
    samples = np.concatenate(samples).astype(np.float64)
    if len(samples) < 3:
        return np.full(3, 1 / np.sqrt(3))
    _, vectors = np.linalg.eigh(np.cov(samples.T))
    axis = vectors[:, -1]
    return axis if axis[np.argmax(np.abs(axis))] > 0 else -axis


def feature_image(image: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The grey image SIFT runs on: the texture along `axis`, 8 bits at mid-grey with a
    fixed gain (a tenth in log intensity is 25.5 levels; the noise is not stretched into
    features where there is no texture)."""
    grey = 127.5 + _GAIN * (_detail(image) @ np.asarray(axis, np.float32))
    return np.round(np.clip(grey, 0, 255)).astype(np.uint8)


def _write_workspace(folder: Path, frames, dilate_px: int) -> None:
    (folder / "images").mkdir(parents=True)
    (folder / "masks").mkdir()
    # No features on highlights, nor outside the field of view (border, overlays).
    masks = [highlight_mask(f.image, dilate_px) | ~f.visible for f in frames]
    axis = texture_axis(frames, masks)
    for frame, hidden in zip(frames, masks, strict=True):
        grey = feature_image(frame.image, axis)
        cv2.imwrite(str(folder / "images" / f"{frame.name}.png"), grey)
        # COLMAP reads the mask of IMAGE.png from MASKS/IMAGE.png.png; 0 = no features.
        cv2.imwrite(
            str(folder / "masks" / f"{frame.name}.png.png"),
            np.where(hidden, 0, 255).astype(np.uint8),
        )


@contextlib.contextmanager
def _quiet_colmap(verbose: bool):
    import pycolmap

    previous = pycolmap.logging.minloglevel
    # Without --verbose, COLMAP's errors too (FATAL only, level 3): the ones it reports on
    # its own ("Failed to create any sparse model") come back here as a `ReconstructionError`,
    # and its glog lines would be printed beside that one line.
    pycolmap.logging.minloglevel = previous if verbose else 3
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = previous


def sparse_reconstruction(
    camera: Camera,
    frames: list[Frame] | tuple[Frame, ...],
    *,
    peak_threshold: float = 0.002,
    max_features: int = 16384,
    highlight_dilate_px: int = 1,
    init_min_tri_angle: float = 4.0,
    seed: int = 0,
    refine_focal: bool = False,
    verbose: bool = False,
    progress: Callable[[str], None] | None = None,
) -> SparseModel:
    """SIFT features (highlights masked), matching, incremental mapping with fixed intrinsics
    (`refine_focal`: the focal lengths refined by bundle adjustment from the camera's,
    the principal point held; `SparseModel.focal_px`).

    `camera` is the undistorted pinhole camera of `frames` (as `load_capture` returns them).
    SIFT runs with a low peak threshold (`peak_threshold`, COLMAP's default is 1/150) so that
    the weakly textured, dim parts of the tissue give points too: the dense surface fitted
    afterwards is only as good as its support. The highlight mask is dilated by only
    `highlight_dilate_px` (the blurred rim): the ring S~ around a highlight, where the BRDF
    is estimated, needs points as close to it as possible. Raises `ReconstructionError`
    when the frames have too few features or no initial pair can be found; a frame that does
    not register is listed in `SparseModel.unregistered`.
    """
    import pycolmap

    say = progress or (lambda message: None)
    frames = sorted(frames, key=lambda f: f.name)
    names = tuple(f.name for f in frames)
    if len(frames) < 2:
        raise ReconstructionError(
            f"structure-from-motion needs at least 2 frames, the capture has {len(frames)}"
        )
    pycolmap.set_random_seed(seed)
    with tempfile.TemporaryDirectory(prefix="ctjax-sfm-") as tmp, _quiet_colmap(verbose):
        folder = Path(tmp)
        _write_workspace(folder, frames, highlight_dilate_px)
        database = folder / "database.db"
        say(f"SIFT features in {len(frames)} frames (highlights masked)")
        keypoints = _extract_features(folder, camera, peak_threshold, max_features)
        matching = "exhaustive" if len(frames) <= EXHAUSTIVE_MAX_FRAMES else "sequential"
        say(f"{matching} matching")
        _match(database, matching, seed)
        held = "the focal length refined" if refine_focal else "intrinsics fixed"
        say(f"incremental mapping ({held})")
        mapping = (folder, len(frames), seed, init_min_tri_angle, refine_focal, say)
        models = _mapped(database, *mapping)
        if matching == "sequential" and _registered(models) < MAPPING_ENOUGH * len(frames):
            # Video order alone can leave the mapper without a start that grows (the
            # cholecystectomy video's 24 frames before every pair was matched up to 40).
            say(f"  {_registered(models)}/{len(frames)} frames registered: matching every pair")
            _match(database, "exhaustive", seed)
            tried = _mapped(database, *mapping, tag="exhaustive")
            if _registered(tried) > _registered(models):
                models, matching = tried, "sequential, then exhaustive"
    # A mapping can end with fewer than two frames registered (its initial pair dropped
    # again): 12 frames of the cholecystectomy video over 1.5 s gave 0 of 12 and 11 points.
    if _registered(models) < 2:
        raise ReconstructionError(
            f"structure-from-motion registered {_registered(models)} of {len(frames)} frames "
            f"({', '.join(f'{n}: {k}' for n, k in sorted(keypoints.items())[:6])} keypoints): "
            "no initial image pair that holds: too little overlap, texture or parallax "
            "between the frames (frames further apart in time move the camera more)"
        )
    model = max(models.values(), key=lambda m: m.num_reg_images())
    return _sparse_model(model, names, keypoints, matching)


def _mapped(database, folder, count, seed, init_min_tri_angle, refine_focal, say, tag=""):
    """Incremental mapping of the matched `database`, run again from another seed (at most
    `MAPPING_ATTEMPTS` seeds), then once from an initial pair `WIDER_START` times further
    apart, while it registers fewer than `MAPPING_ENOUGH` of the `count` frames; the
    reconstructions (by index) of the run that registers the most."""
    import pycolmap

    runs = [(seed + k, init_min_tri_angle) for k in range(MAPPING_ATTEMPTS)]
    runs.append((seed, WIDER_START * init_min_tri_angle))
    models = {}
    for attempt, (run_seed, angle) in enumerate(runs):
        # The initial pair decides much: on real frames (a sinus video at 640x360) one
        # seed registered 0 of 12 frames from an 8-point start, the next all 12.
        if attempt:
            again = f"seed {run_seed}"
            if angle != init_min_tri_angle:
                again = f"an initial pair at least {angle:g} degrees apart"
            say(f"  {_registered(models)}/{count} frames registered: mapping again ({again})")
        tried = pycolmap.incremental_mapping(
            database,
            folder / "images",
            folder / f"sparse{tag}{attempt}",
            _mapping_options(run_seed, angle, refine_focal),
        )
        if _registered(tried) > _registered(models):
            models = tried
        if _registered(models) >= MAPPING_ENOUGH * count:
            break
    return models


# Incremental mapping is run again from another seed (at most this many seeds) while it
# registers fewer than this share of the frames...
MAPPING_ATTEMPTS = 3
MAPPING_ENOUGH = 0.75
# ...and then once from an initial pair this many times further apart in angle (COLMAP's
# default of 16 degrees): frames close together make a close initial pair, whose points are
# filtered away as too flat. The cholecystectomy video's first 3 s in 24 frames: 6 of 24
# frames and no point for seeds 0-2 at 4 degrees (and seed 0 at 8), 24 and 3574 points at
# 16; its 24 frames over 8 s matched in video order: 3-4 of 24 at 4 degrees, 24 and 4865
# points at 16. (At 8 degrees in one run every capture that registers at 4 registered as
# many frames: the cholecystectomy's 12 and 24 frames over 8 s, the sinus's 12 and 24,
# SCARED 61-72; but the first runs stay at 4: theirs are the reconstructions measured.)
WIDER_START = 4.0


def _registered(models) -> int:
    """The most frames one of `models` (pycolmap reconstructions by index) registers."""
    return max((m.num_reg_images() for m in models.values()), default=0)


def _keypoint_counts(database: Path) -> dict[str, int]:
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        return {
            Path(image.name).stem: int(db.num_keypoints_for_image(image.image_id))
            for image in db.read_all_images()
        }
    finally:
        db.close()


def _sparse_model(model, names, keypoints, matching) -> SparseModel:
    (camera,) = model.cameras.values()  # one camera (`CameraMode.SINGLE`), PINHOLE
    focal = (float(camera.params[0]), float(camera.params[1]))
    cam_from_world = {}
    for image in model.images.values():
        if not image.has_pose:
            continue
        matrix = np.eye(4)
        matrix[:3] = image.cam_from_world().matrix()
        cam_from_world[Path(image.name).stem] = matrix
    points = model.points3D.values()
    xyz = np.array([p.xyz for p in points], np.float64).reshape(-1, 3)
    errors = np.array([p.error for p in points], np.float64)
    tracks = np.array([p.track.length() for p in points], np.int64)
    return SparseModel(
        names=names,
        registered=tuple(n for n in names if n in cam_from_world),
        cam_from_world=cam_from_world,
        points=xyz,
        point_errors=errors,
        track_lengths=tracks,
        keypoints=keypoints,
        matching=matching,
        mean_reprojection_error=float(model.compute_mean_reprojection_error()),
        focal_px=focal,
    )


def _extract_features(folder: Path, camera: Camera, peak_threshold, max_features) -> dict:
    """SIFT into the workspace's database with the camera's intrinsics; keypoints per frame.

    Raises `ReconstructionError` when fewer than two frames have enough keypoints."""
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    # COLMAP's pixel centres are at +0.5 (ctjax's, like OpenCV's, at integers).
    intrinsics = (
        float(camera.fx),
        float(camera.fy),
        float(camera.cx) + 0.5,
        float(camera.cy) + 0.5,
    )
    reader.camera_params = ",".join(f"{value:.17g}" for value in intrinsics)
    reader.mask_path = str(folder / "masks")
    extraction = pycolmap.FeatureExtractionOptions()
    # One thread: with several, the same images reconstructed twice differed now and then
    # (4 runs in 12 on a 192x160 x 4 capture: reprojection error 0.11349 vs 0.11355 px), as
    # did 640x512 x 8 ones (0.3676644 vs 0.3676643); on one, 12 runs in 12 are identical.
    # It costs 6.5-6.8 s instead of 4.8-5.4 s for reconstruct_capture at 640x512 x 8.
    extraction.num_threads = 1
    extraction.sift.peak_threshold = peak_threshold
    extraction.sift.max_num_features = max_features
    database = folder / "database.db"
    pycolmap.extract_features(
        database,
        folder / "images",
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    keypoints = _keypoint_counts(database)
    poor = {n: k for n, k in keypoints.items() if k < MIN_KEYPOINTS}
    if len(keypoints) - len(poor) < 2:
        listing = ", ".join(f"{n}: {k}" for n, k in sorted(keypoints.items())[:6])
        raise ReconstructionError(
            f"too few features for structure-from-motion ({listing} SIFT keypoints; at "
            f"least {MIN_KEYPOINTS} per frame needed): the images look untextured"
        )
    return keypoints


def _match(database: Path, matching: str, seed: int) -> None:
    """Exhaustive matching for short sequences, sequential (with overlap) beyond; the
    geometric verification's RANSAC seeded (COLMAP's default, -1, seeds it from the clock:
    two reconstructions of the same 640x512 x 8 images then differed by 5 of 2034 points
    and 0.2-0.37 mm of depth, and the BRDF fitted on them by up to 6 points of F_tilde)."""
    import pycolmap

    match_options = pycolmap.FeatureMatchingOptions()
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = seed
    if matching == "exhaustive":
        pycolmap.match_exhaustive(
            database,
            matching_options=match_options,
            verification_options=verification,
            device=pycolmap.Device.cpu,
        )
        return
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = _SEQUENTIAL_OVERLAP
    pycolmap.match_sequential(
        database,
        matching_options=match_options,
        pairing_options=pairing,
        verification_options=verification,
        device=pycolmap.Device.cpu,
    )


def _mapping_options(seed: int, init_min_tri_angle: float, refine_focal: bool = False):
    """Incremental mapping with the intrinsics held fixed (but the focal lengths with
    `refine_focal`), deterministic for a seed."""
    import pycolmap

    options = pycolmap.IncrementalPipelineOptions()
    options.ba_refine_focal_length = refine_focal
    options.ba_refine_principal_point = False
    options.ba_refine_extra_params = False
    options.multiple_models = False
    options.random_seed = seed
    options.mapper.random_seed = seed
    options.triangulation.random_seed = seed
    # One thread: Ceres's multi-threaded bundle adjustment sums in a varying order, and the
    # 1e-8 differences it leaves grow through the photometric refinement (three
    # reconstructions of the same images gave sigma +0.9..+2.0% with threads).
    options.num_threads = 1
    options.mapper.num_threads = 1
    # A laparoscope sweeps a few degrees: COLMAP's 16-degree default for the initial pair
    # is rarely reached.
    options.mapper.init_min_tri_angle = init_min_tri_angle
    # Keep points seen in two frames only: short sequences have many, and the robust
    # surface fit copes with the few bad ones.
    options.triangulation.ignore_two_view_tracks = False
    return options
