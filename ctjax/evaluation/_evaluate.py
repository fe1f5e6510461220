"""`ctjax evaluate`: the paper's evaluation (section 7) of Lambertian against Cook-Torrance.

Both models are fitted on the first N frames (calibration) and compared on the rest (test):
(i) RGB error on the calibration frames, (ii) on the test frames, (iii) shape from shading
on the test frames, brought to metric scale by the known bounding-box volume, against the
capture's depth.
"""

import dataclasses
import inspect
import math
import time
from collections.abc import Callable, Sequence

import cv2
import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._determined import MIN_LOBE_GAIN, Undetermined
from .._errors import CtjaxError
from .._json import named_parameters
from .._result import Estimate
from .._status import Status
from .._threads import checked_workers, in_order
from .._units import METRIC, length_unit_of
from ..effects import image_effects
from ..estimation import ALBEDO_CHOICES, default_albedo, why_no_albedo_map
from ..fitting import (
    MAP_LM_DTYPE,
    ShadingModel,
    facets_suggestion,
    fit_model,
    fit_model_map,
    paper_model,
    pixel_columns,
    pixel_predict,
    rmse_levels,
)
from ..fitting._parameters import free_parameters
from ..heldout import HeldOutTracks, RightViews, frame_consistency, split_frames
from ..io import Capture
from ..lights import AbstractLight, ColocatedLight, LightField
from ..lobes import BRDF, Lambertian
from ..observations import Observations
from ._evaluation import Evaluation, FrameShape
from ._pyramid import block_reduce, reduced
from ._scale import bounding_box_volume
from ._sfs import sfs_cook_torrance, sfs_refined, sfs_tsai_shah

# An estimator of Cook-Torrance with its light: fits on the first `calibration` frames.
Estimator = Callable[..., Estimate]
# Shape from shading runs on the frame reduced so that it is at most this wide (its sparse
# Gauss-Newton solve grows faster than the pixel count).
SFS_MAX_WIDTH = 160
# "Near highlights": within this many full-resolution pixels of the specular set S.
HIGHLIGHT_RADIUS_PX = 12
# Lambert under Cook-Torrance's light this much worse on the test frames than under a
# light at the lens: the light fitted on the calibration frames does not carry to them.
LIGHT_CARRIES_WITHIN = 0.02


def fit_lambertian(
    capture: Capture,
    frames: list[int],
    max_samples: int = 40_000,
    *,
    tracks: HeldOutTracks | None = None,
    light: AbstractLight | None = None,
    diffuse: Lambertian | None = None,
    effects: tuple = (),
    hold_effects: bool = False,
) -> Estimate:
    """The Lambertian model (rho_tilde, light at the camera) fitted to every usable pixel of
    `frames`: linear, so the closed form is the least-squares solution. With `tracks` (an
    albedo map), one albedo per tracked surface point of `tracks.train`, eliminated in
    closed form as for Cook-Torrance: the model's `rho_tilde` is their median. `light`:
    another light, held as it is (e.g. Cook-Torrance's fitted one: its offset and
    falloff), so that the two models differ by the lobe alone. `diffuse`: another diffuse
    lobe in place of Lambert's (e.g. Cook-Torrance's fitted `OrenNayar`), its shape fitted
    from where it is. `effects`: image effects fitted with the rest, from these values;
    `hold_effects`: held at them instead, as the light is (Cook-Torrance's fitted ones: a
    knee or exposures refitted without the lobe moved Lambert's test-frame error by more
    than the lobe did, on the second sinus video 9.96 -> 10.50 levels against the lobe's
    9.94, and were counted as the lobe's gain)."""
    lobe = Lambertian(1.0) if diffuse is None else diffuse
    light = ColocatedLight() if light is None else light
    start = ShadingModel(BRDF(lobe), light, tuple(effects))
    held_parts = ("light", "effects") if hold_effects else ("light",)
    held = [p.name for p in free_parameters(start) if p.name.startswith(held_parts)]
    if tracks is not None:
        return fit_model_map(start, tracks.train, freeze=held, dtype=MAP_LM_DTYPE)
    samples = Observations.of(capture).pixels(frames, max_samples=max_samples)
    return fit_model(
        start, samples, pixel_predict, columns=pixel_columns, max_steps=20, freeze=held
    )


def fit_colocated(capture: Capture, calibration: int, albedo: str | None = None) -> Estimate:
    """The paper's estimate (`ctjax fit`: BnB on the ring, L = V) on the first
    `calibration` frames, with a 10 px ring (the paper's 3 px is thin on bright tissue);
    `albedo` as `fit_capture`'s; one exposure (`evaluate --effects` fits the frames' in both
    models)."""
    from ..estimation import MaskOptions, fit_capture

    capture = Observations.of(capture).capture
    subset = dataclasses.replace(capture, frames=capture.frames[:calibration])
    fit = fit_capture(subset, MaskOptions(ring_px=10), albedo=albedo, effects=())
    fit.details["light"] = "colocated"
    return fit


def _cook_torrance(cook_torrance, albedo, diffuse, effects, progress) -> Callable[..., Estimate]:
    """Cook-Torrance's fit as a function of (capture, calibration), its options checked
    here: before any fit, so that a wrong one is refused in a second, not after two fits.
    An estimator that reports its progress (`calibrate_near_light`: minutes on a real
    capture) reports it through `progress`, indented under evaluate's own steps."""
    if effects and isinstance(cook_torrance, Estimate | ShadingModel):
        raise CtjaxError(
            "effects are fitted by Cook-Torrance's estimator: a fitted model is used as it is "
            "(give the estimator, e.g. calibrate_near_light, or the model with its effects)"
        )
    if isinstance(cook_torrance, Estimate):
        return lambda capture, calibration: cook_torrance
    if isinstance(cook_torrance, ShadingModel):
        return lambda capture, calibration: Estimate(cook_torrance, status=Status.given)
    if callable(cook_torrance):
        try:
            parameters = inspect.signature(cook_torrance).parameters
        except (TypeError, ValueError):
            parameters = {}
        options = {"albedo": albedo} if "albedo" in parameters else {}
        if diffuse is not Lambertian:
            if "diffuse" not in parameters:
                raise CtjaxError(
                    f"diffuse={diffuse.__name__}: the Cook-Torrance estimator "
                    f"{getattr(cook_torrance, '__name__', cook_torrance)!r} takes no diffuse "
                    "term (calibrate_near_light does)"
                )
            options["diffuse"] = diffuse
        if effects:
            if "effects" not in parameters:
                raise CtjaxError(
                    "effects: the Cook-Torrance estimator "
                    f"{getattr(cook_torrance, '__name__', cook_torrance)!r} fits no image effects "
                    "(calibrate_near_light does)"
                )
            options["effects"] = effects
        if "progress" in parameters:
            options["progress"] = lambda message: progress(f"  {message}")
        return lambda capture, calibration: _on_calibration_frames(
            cook_torrance, capture, calibration, options
        )
    raise CtjaxError(
        "cook_torrance must be a fitted ShadingModel, an Estimate or an estimator "
        f"(capture, calibration=N) -> Estimate, got {type(cook_torrance).__name__}"
    )


def _near_highlight(image: np.ndarray, mask: np.ndarray, saturation=1.0) -> np.ndarray:
    from ..specular import specular_sets

    # S as the fits find it: a channel at the camera's ceiling reads as clipped.
    specular = specular_sets(image, mask, saturation_level=np.asarray(saturation)).specular
    if not specular.any():
        return np.zeros_like(mask)
    distance = cv2.distanceTransform((~specular).astype(np.uint8), cv2.DIST_L2, 5)
    return distance <= HIGHLIGHT_RADIUS_PX


def frame_shapes(
    capture: Capture,
    index: int,
    lambertian: ShadingModel,
    cook_torrance: ShadingModel,
    max_width: int = SFS_MAX_WIDTH,
    reference: Capture | None = None,
    per_pixel: bool = False,
) -> FrameShape:
    """Both SfS of one frame against its depth (or `reference`'s), at reduced resolution."""
    source = reference or capture  # its frame's image and depth
    frame = source.frames[index]
    if frame.depth is None:
        raise CtjaxError(f"frame {frame.name}: SfS is compared with depth; the frame has none")
    factor = max(1, math.ceil(capture.camera.width / max_width))
    camera = reduced(capture.camera, factor)
    valid = frame.geometry_mask
    mask = block_reduce(valid, factor, np.all)
    image = block_reduce(frame.image, factor)
    reference = np.where(mask, block_reduce(np.where(valid, frame.depth, 0.0), factor), np.nan)
    near = block_reduce(_near_highlight(frame.image, valid, source.saturation), factor, np.any)
    if mask.sum() < 9:
        raise CtjaxError(f"frame {frame.name}: too few pixels with depth for SfS")
    volume = bounding_box_volume(reference, mask, camera)
    rho = np.asarray(named_parameters(lambertian.brdf)["rho_tilde"])
    clipped = {"saturation": source.saturation}  # the camera's ceilings, as the fits'
    tsai_shah, log_depth = sfs_tsai_shah(image, mask, camera, rho, volume, **clipped)
    joint, _ = sfs_cook_torrance(image, mask, camera, cook_torrance, volume, **clipped)
    paper = None
    if per_pixel:
        paper = sfs_refined(
            image, mask, camera, cook_torrance, log_depth, volume, rounds=1, **clipped
        )
    return FrameShape(frame.name, image, reference, tsai_shah, joint, mask, near, paper)


def _check_sfs_reference(frame, camera) -> None:
    """SfS is scored against `frame`'s depth, scaled by its bounding box's volume: that box
    must have a volume (depth at several pixels, not flat along an axis)."""
    if frame.depth is None:
        raise CtjaxError(f"frame {frame.name}: SfS is compared with depth; the frame has none")
    mask = frame.geometry_mask
    if mask.sum() < 9:
        raise CtjaxError(f"frame {frame.name}: too few pixels with depth for SfS")
    if not bounding_box_volume(frame.depth, mask, camera) > 0:
        raise CtjaxError(
            f"frame {frame.name}: its depth is flat along an axis (bounding box of volume 0): "
            "shape from shading is scored at the scale of that volume (evaluate with "
            "--no-sfs, or give depth with relief)"
        )


def _on_calibration_frames(estimator, capture, calibration: int, options: dict) -> Estimate:
    """`estimator` on a capture of the first `calibration` frames alone (its own held-out
    choices among them, `calibration=None`): nothing it chooses or fits sees a test frame.
    `calibrate_near_light` chooses its falloff on frames it holds out and then refits the
    chosen model on every frame it is given; given the whole capture, those were the test
    frames (on SCARED 91-102, 12 frames: sigma 0.347 and 0.980x Lambert's test RMSE under
    the same light, against 0.202 and 0.993x on the calibration frames alone; before
    2026-12-07). The model's per-frame parameters (`PER_FRAME`: an exposure per frame) are
    padded for the test frames where the estimator made them for its frames alone
    (`_padded_per_frame`); the held-out protocol fits a test frame's on its own views."""
    obs = Observations.of(capture)
    subset = dataclasses.replace(obs.capture, frames=obs.capture.frames[:calibration])
    estimate = estimator(subset, calibration=None, **options)
    estimate.model = _padded_per_frame(estimate.model, len(obs))
    estimate.details["parameters_from"] = (
        f"the calibration frames alone ({calibration}), chosen on some of them held out"
    )
    return estimate


def _padded_per_frame(model, frames: int):
    """`model` with each per-frame parameter (`PER_FRAME`: one value per frame after the
    first, as `FrameExposure`'s) padded with 0 up to `frames` frames: an estimator given the
    calibration frames alone, with the effects built for the whole capture (as `evaluate`
    builds them), already has every frame's; one that built its own for the calibration
    frames has theirs."""
    per_frame = [p for p in free_parameters(model) if p.per_frame]

    def padded(value):
        value = jnp.asarray(value)
        missing = max(frames - 1 - value.shape[0], 0)
        return jnp.concatenate([value, jnp.zeros((missing, *value.shape[1:]), value.dtype)])

    if not per_frame:
        return model
    return eqx.tree_at(
        lambda m: [p.get(m) for p in per_frame], model, [padded(p.get(model)) for p in per_frame]
    )


def evaluate(
    capture: Capture,
    *,
    calibration: int | None = None,
    cook_torrance: Estimator | Estimate | ShadingModel | None = None,
    albedo: str | None = None,
    sfs: bool = True,
    reference: Capture | None = None,
    per_pixel_sfs: bool = False,
    progress: Callable[[str], None] = lambda message: None,
    workers: int | None = None,
    diffuse: type[Lambertian] = Lambertian,
    facets: bool | str = False,
    facet_marginal: bool = False,
    effects: Sequence = (),
) -> Evaluation:
    """Fit Lambertian and Cook-Torrance on the calibration frames and evaluate both on the
    test frames (RGB error and SfS).

    `cook_torrance`: how Cook-Torrance and its light are obtained: an estimator called as
    `cook_torrance(capture, calibration=N[, albedo=...])` (default: `calibrate_near_light`;
    also `calibrate_light_field`, `fit_colocated`), or an already fitted `Estimate` or
    `ShadingModel`, used as is. `albedo`: `"map"` (one albedo per surface point, for both
    models: the default when every frame has depth and a pose) or `"uniform"` (one per
    model, the paper's); with the map, the RGB errors are those of tracked surface points,
    each view predicted with the model fixed and the point's albedo fitted to its other
    views (the held-out protocol, `HeldOutTracks`), the same freedom for both models.
    `reference`: the capture whose depth the SfS is compared with (default: `capture`'s
    own; e.g. ground truth when `capture`'s shape came from structure-from-motion).
    `per_pixel_sfs`: also run the paper's per-pixel Cook-Torrance SfS (eq. 9 on Tsai-Shah's
    normals) and report it beside the joint one. Shape from shading has one image: it uses
    one albedo per model (with the map, the median of the points'), and says so in `notes`.
    `workers`: test frames whose shape from shading runs at once, on threads (default: the
    cores, at most 4); the results do not depend on it. `diffuse`: Cook-Torrance's diffuse
    term (`ctjax.lobes.diffuse_lobes`), given to its estimator; where it is not Lambert's,
    that term alone under the same light is fitted too (`diffuse_same_light`), and the
    gain is split into the light's, the diffuse term's and the lobe's. `facets`: also the
    lobe about every tracked point's own facet under Cook-Torrance's light
    (`ctjax.fitting.facet_lobe`, with the map only): sigma and F_tilde chosen on the
    calibration frames, the test frames' views predicted with each point's facet and albedo
    chosen from its other views, beside Lambert's under the same light; `"auto"` (the
    command's default): only where `ctjax.fitting.facets_suggestion` points there;
    `facet_marginal`: with them, the facets integrated out and the facet lobe at that width
    (`HeldOutTracks.facet_blocks`), nested in their JSON. `effects`: image effects both
    models fit with the rest (`ctjax.effects.image_effects`: effects or their names, e.g.
    `("frame_exposure",)` for a scope's auto-exposure; with the map only), each per-frame
    one fitted on the held-out frames where they are judged; the facets are then judged on
    the views with the effects undone (`HeldOutTracks.in_radiance`)."""
    workers = checked_workers(workers)
    if facets not in (True, False, "auto"):
        raise CtjaxError(f"facets must be True, False or 'auto', got {facets!r}")
    missing = [f.name for f in capture.frames if f.depth is None or f.normals is None]
    if missing:
        raise CtjaxError(
            f"{capture.root}: evaluate needs depth and normals for every frame (missing for "
            f"{', '.join(missing[:5])}); run `ctjax reconstruct` first"
        )
    if cook_torrance is None:
        from ..calibration import calibrate_near_light

        cook_torrance = calibrate_near_light
    capture = Observations.of(capture)
    unmapped = why_no_albedo_map(capture) if albedo is None else None
    albedo = default_albedo(capture) if albedo is None else albedo
    if albedo not in ALBEDO_CHOICES:
        raise CtjaxError(f"albedo must be one of {ALBEDO_CHOICES}, got {albedo!r}")
    calib, test = split_frames(len(capture), calibration, source=capture.root)
    if effects:
        if albedo != "map":
            raise CtjaxError(
                "effects are judged with the albedo map (a frame's exposure is fitted on its "
                f"own views of the tracked points): not with albedo {albedo!r}"
            )
        effects = image_effects(effects, paper_model(), capture.candidate_context())
    if facets is True and albedo != "map":  # asked: refused before any fit, as fit does
        raise CtjaxError(
            "the facets are judged with the albedo map (each point's facet read from its own "
            f"views): not with albedo {albedo!r}"
        )
    if sfs:  # before any fit: a capture SfS cannot be scored on fails in a second
        for index in test:
            _check_sfs_reference((reference or capture).frames[index], capture.camera)
    fit_cook_torrance = _cook_torrance(cook_torrance, albedo, diffuse, effects, progress)
    tracks = HeldOutTracks.split(capture, len(calib)) if albedo == "map" else None
    timings, notes = {}, [unmapped] if unmapped else []
    tic = time.perf_counter()
    progress(f"fitting the Lambertian model on frames {calib} (albedo {albedo})...")
    lambertian = fit_lambertian(capture, calib, tracks=tracks, effects=effects)
    timings["lambertian_fit"] = time.perf_counter() - tic
    tic = time.perf_counter()
    progress(f"fitting Cook-Torrance with its light on frames {calib}...")
    fitted = fit_cook_torrance(capture, len(calib))
    timings["cook_torrance_fit"] = time.perf_counter() - tic
    tic = time.perf_counter()
    same_light = same_diffuse = None
    light = fitted.model.light
    if not isinstance(light, ColocatedLight) or light.falloff:
        progress("fitting the Lambertian model under Cook-Torrance's light (held)...")
        same_light = fit_lambertian(
            capture, calib, tracks=tracks, light=light, effects=fitted.model.effects,
            hold_effects=True,
        )  # fmt: skip
    own = _diffuse_of(fitted.model)
    if own is not None:
        progress(f"fitting Cook-Torrance's diffuse term ({type(own).__name__}) alone...")
        same_diffuse = fit_lambertian(
            capture, calib, tracks=tracks, light=light, diffuse=own, effects=fitted.model.effects,
            hold_effects=True,
        )  # fmt: skip
    timings["lambertian_same_light_fit"] = time.perf_counter() - tic
    tic = time.perf_counter()
    lambertian, fitted = (_judged(capture, e, calib, test, tracks) for e in (lambertian, fitted))
    if same_light is not None:
        same_light = _judged(capture, same_light, calib, test, tracks)
        fitted = _seen_in_new_frames(fitted, same_light)
    if same_diffuse is not None:
        same_diffuse = _judged(capture, same_diffuse, calib, test, tracks)
    budgets = frames_rmse = None
    if tracks is not None:
        budgets = _budgets(tracks, {"lambertian": lambertian, "cook_torrance": fitted})
        models = {"lambertian": lambertian.model, "cook_torrance": fitted.model}
        frames_rmse = frame_consistency(tracks, models)
    timings["rgb_error"] = time.perf_counter() - tic
    names = [capture.frames[index].name for index in test]
    note = light_not_carried(lambertian, same_light, frames_rmse, names)
    notes += [note] if note else []
    facet, why = None, None
    if facets == "auto" and budgets is not None:
        left = budgets["cook_torrance"].get("highlight_share")
        why = facets_suggestion(Status(fitted.status).name, left)
    if facets is True or why is not None:
        tic = time.perf_counter()
        marginal = ", and integrated out: minutes" if facet_marginal else ""
        progress(f"the lobe about every point's own facet (a grid of sigma, F_tilde{marginal})...")
        off = set((frames_rmse or {}).get("brightness_off", []))
        unsteady = [index for index in test if capture.frames[index].name in off]
        facet = _facet_lobe(tracks, fitted.model, why, facet_marginal, unsteady)
        timings["facets"] = time.perf_counter() - tic
    right_views = None
    if albedo == "map" and capture.capture.stereo is not None:
        tic = time.perf_counter()
        progress(f"both models on the right camera's views of frames {calib}...")
        fits = {
            "lambertian": lambertian,
            "lambertian_same_light": same_light,
            "diffuse_same_light": same_diffuse,
        }
        right_views, note = _on_right_views(capture, calib, {**fits, "cook_torrance": fitted})
        notes += [note] if note else []
        timings["right_views"] = time.perf_counter() - tic
    shapes = []
    if sfs:
        tic = time.perf_counter()
        names = ", ".join(capture.frames[index].name for index in test)
        progress(f"shape from shading of test frames {names}...")

        def shapes_of(index):
            return frame_shapes(
                capture,
                index,
                lambertian.model,
                fitted.model,
                reference=reference,
                per_pixel=per_pixel_sfs,
            )

        shapes = list(in_order(shapes_of, test, workers))
        timings["sfs"] = time.perf_counter() - tic
    notes += [
        f"{name} fit: {e.status.message}"
        for name, e in (("Lambertian", lambertian), ("Cook-Torrance", fitted))
        if not e.converged
    ]
    if albedo == "map" and sfs:
        notes.append(
            "shape from shading uses one albedo per model (the median of the surface "
            "points' albedos): one image cannot tell texture from shading"
        )
    unit = length_unit_of(capture)
    return Evaluation(
        calib, test, lambertian, fitted, shapes, timings, notes, albedo, same_light, unit,
        right_views, same_diffuse, budgets, facet, frames_rmse,
    )  # fmt: skip


def _facet_lobe(tracks, model, why=None, marginal=False, unsteady=()) -> dict:
    """`facet_lobe`'s JSON under `model`'s light, why it was judged (`why`, None: asked) and
    with `marginal` the other `HeldOutTracks.facet_blocks` in it. A model with image
    effects: on the views with its effects undone (`in_radiance`). `unsteady`: the test
    frames whose brightness the model does not follow, judged again without (`facet_lobe`)."""
    judged = "asked (facets=True)" if why is None else f"by itself: {why}"
    blocks = tracks.model_facet_blocks(model, marginal=marginal, unsteady=unsteady)
    return blocks.pop("facets") | {"judged": judged} | blocks


def _budgets(tracks: HeldOutTracks, fits: dict) -> dict:
    """What is left of each model's residual on the test frames (`heldout_budget`)."""
    from ..diagnostics import heldout_budget

    out = {}
    for name, fit in fits.items():
        try:
            out[name] = heldout_budget(tracks, fit.model).to_json()
        except ValueError as error:  # too few judged views
            out[name] = {"note": str(error)}
    return out


def _diffuse_of(model: ShadingModel) -> Lambertian | None:
    """The model's diffuse lobe where it is not Lambert's (a `Lambertian` subclass with a
    shape, e.g. `OrenNayar`); None otherwise."""
    for lobe in model.brdf.lobes:
        if isinstance(lobe, Lambertian) and type(lobe) is not Lambertian:
            return lobe
    return None


def _on_right_views(capture: Observations, calib, fits: dict) -> tuple[dict | None, str | None]:
    """Each fit's RMSE on the right camera's views of the calibration frames (the same
    instants the models were fitted on, another viewpoint, the light where it was), and on
    the left views of the same points; or None and why not."""
    if capture.capture.length_unit != METRIC:
        return None, (
            "right views not judged: the depth is not in mm (reconstruct the stereo capture)"
        )
    if isinstance(fits["cook_torrance"].model.light, LightField):
        return None, (
            "right views not judged: a per-pixel light field is the left camera's "
            "(one direction per left pixel)"
        )
    views = RightViews.of(capture, calib)
    out = {name: views.rmse(fit.model) for name, fit in fits.items() if fit is not None}
    return {
        "frames": calib,
        "views": next(iter(out.values()))["views"],
        **{f"{name}_rgb_rmse": {k: v[k] for k in ("right", "left")} for name, v in out.items()},
        "note": (
            "8-bit levels on the right camera's images of the calibration frames (the same "
            "instants, a baseline away, the light beside the left lens: V moves, L does not), "
            "each view predicted with the model fixed and the point's albedo fitted to its "
            "other views; left: the same points' left views the same way"
        ),
    }, None


def _seen_in_new_frames(fitted: Estimate, same_light: Estimate) -> Estimate:
    """`fitted` (judged) as `no_lobe` where its lobe, `successful` on the calibration frames,
    predicts the test frames no better than Lambert's model under the same light: no lobe
    is seen in new frames (the facet lobe's rule, `judged_status`: better by `MIN_LOBE_GAIN`
    at least). The second sinus video's 28 frames with red read as clipped from 209:
    1.003x, said `successful` before this."""
    rmse, reference = fitted.rmse["test"], same_light.rmse["test"]
    no_better = 1 - MIN_LOBE_GAIN
    if Status(fitted.status) != Status.successful or not rmse >= no_better * reference > 0:
        return fitted
    why = (
        f"on the test frames Cook-Torrance predicts the views {rmse / reference:.3f}x as far "
        f"off as Lambert's model under the same light (not {MIN_LOBE_GAIN:.1%} better): no "
        "specular lobe is seen in new frames, however well the calibration frames chose it"
    )
    found = Undetermined("F_tilde", Status.no_lobe, why).to_json()
    undetermined = [found, *fitted.details.get("undetermined", [])]
    return dataclasses.replace(
        fitted,
        status=Status.no_lobe,
        details={**fitted.details, "undetermined": undetermined},
        warnings=[*fitted.warnings, why],
    )


def light_not_carried(lambertian, same_light, frames_rmse, test_names) -> str | None:
    """A note where Lambert's model under Cook-Torrance's light (fitted on the calibration
    frames) predicts the test frames more than `LIGHT_CARRIES_WITHIN` worse than under the
    light at the lens (`lambertian`): that light does not carry to new frames, and the
    lobe's ratio is then over a worse base. With the test frames whose brightness the model
    does not follow (`frame_consistency`'s `brightness_off`), where any. SCARED's frames
    179-190 (2026-12-07): 28.76 against 20.13 levels, frames 189 and 190 at 0.79 and 0.68 of
    the brightness predicted."""
    if same_light is None:
        return None
    at_lens, lit = lambertian.rmse["test"], same_light.rmse["test"]
    if not (at_lens > 0 and lit > (1 + LIGHT_CARRIES_WITHIN) * at_lens):
        return None
    note = (
        f"Cook-Torrance's light, fitted on the calibration frames, predicts the test frames "
        f"{lit / at_lens:.3f}x as far off as a light at the lens (Lambert's model under each: "
        f"{lit:.2f} against {at_lens:.2f} levels): it does not carry to new frames, and the "
        "lobe's ratio to Lambert's model under it is over a worse base"
    )
    off = [n for n in (frames_rmse or {}).get("brightness_off", []) if n in test_names]
    if off:
        note += (
            f"; the model does not follow the brightness of test frame(s) {', '.join(off)} "
            "(a scope's auto-exposure: --effects frame_exposure)"
        )
    return note


def _judged(capture: Observations, fit: Estimate, calib, test, tracks) -> Estimate:
    """`fit` with its RMSE on the calibration and the test frames: every usable pixel (one
    albedo), or with `tracks` every view of the tracked points, predicted from the albedo
    of the point's other views (an albedo map)."""
    if tracks is not None:
        rmse = tracks.rmse(fit.model)
        rmse = {"calibration": rmse["calibration"], "test": rmse["heldout"]}
    else:
        rmse = {
            split: float(rmse_levels(fit.model, capture.pixels(frames), pixel_predict))
            for split, frames in (("calibration", calib), ("test", test))
        }
    return dataclasses.replace(fit, rmse=rmse, frames={"calibration": calib, "test": test})
