"""`ctjax fit`: the BRDF of a capture, by the albedo map (`_map_fit.py`) or the paper's one
albedo (`_uniform_fit.py`)."""

import functools

from .._errors import CtjaxError
from .._result import Estimate
from .._status import Status
from ..io import Capture
from ..observations import Observations
from ..specular import MaskOptions, flag_misoriented
from ._brdf import PAPER, BRDFFamily
from ._map_fit import fit_albedo_map
from ._uniform_fit import DEFAULT_MASKS, fit_uniform

ALBEDO_CHOICES = ("map", "uniform")


def default_albedo(capture: "Capture | Observations") -> str:
    """`"map"` when the capture has several frames, all with depth and a pose (the albedo
    map follows surface points across them), else `"uniform"` (the paper's model)."""
    frames = capture.frames
    if len(frames) > 1 and all(f.pose is not None and f.depth is not None for f in frames):
        return "map"
    return "uniform"


def why_no_albedo_map(capture: "Capture | Observations") -> str | None:
    """Where the default is the uniform albedo (`default_albedo`) only because some frames
    lack a pose or depth while others have theirs (one frame missing from poses.json): a
    warning naming them (`fit_capture`'s, the light calibrations' and `evaluate`'s, which
    gives it as a note); None where the map is the default, or where no frame has a pose
    (the paper's uniform albedo is then what is meant)."""
    frames = capture.frames
    if len(frames) < 2 or default_albedo(capture) == "map":
        return None
    if not any(f.pose is not None for f in frames):
        return None
    lacking = []
    for frame in frames:
        missing = [what for what in ("pose", "depth") if getattr(frame, what) is None]
        if missing:
            lacking.append(f"{frame.name} (no {' or '.join(missing)})")
    return (
        f"{capture.root}: frame(s) {', '.join(lacking[:5])}"
        + (f" and {len(lacking) - 5} more" if len(lacking) > 5 else "")
        + ": the albedo map follows surface points across frames by their depth and pose, "
        "so the uniform albedo (the paper's) is fitted instead; add what is missing (poses.json, "
        "depth/) or reconstruct the shape (`ctjax reconstruct --force`), or pass --albedo "
        "uniform to say so"
    )


def fit_capture(
    capture: "Capture | Observations",
    masks: MaskOptions = DEFAULT_MASKS,
    family: BRDFFamily = PAPER,
    *,
    tolerance: float = 1e-3,
    albedo: str | None = None,
    max_points: int | None = None,
    right_views: bool = False,
    effects: tuple[str, ...] | None = None,
) -> Estimate:
    """Estimate the BRDF of a capture: the paper's light (co-located with the camera,
    L = V) and its model (`family`) by default.

    `albedo="map"` (the default when every frame has depth and a pose, `default_albedo`):
    one rho_tilde per surface point and channel, with F_tilde and sigma shared, from all
    frames (`fit_albedo_map`): the estimate for textured tissue. `albedo="uniform"`: the
    paper's model, one rho_tilde, fitted on the ring S~ of every frame (below).
    `right_views`: with the map, a stereo capture's right images too (`fit_albedo_map`).
    `effects`: image effects fitted with the BRDF, by name: `"frame_exposure"` (a gain per
    frame, a scope's auto-exposure), with the map; the others need a light model that
    takes them (`ctjax.calibration.calibrate_near_light(effects=...)`); `()` for none (one
    exposure, the paper's). None (the default): a gain per frame where the data ask for
    it (`with_exposure_where_needed`): with the map, the fit without first, and where its
    frames are brighter or darker than the others predict and undoing that moves the lobe
    (`Status.brightness_off`), the fit with each frame's exposure instead, saying so in
    `details["exposure"]`.
    Either way the estimate carries the highlights' alignment
    (`ctjax.specular.flag_misoriented`): where one rotation of the normals would put the
    highlights at N = H, the lobe is no measurement (`Status.misoriented`).
    """
    unmapped = why_no_albedo_map(capture) if albedo is None else None
    albedo = default_albedo(capture) if albedo is None else albedo
    if albedo not in ALBEDO_CHOICES:
        raise CtjaxError(f"albedo must be one of {ALBEDO_CHOICES}, got {albedo!r}")
    if right_views and albedo != "map":
        raise CtjaxError("the right views are fitted with the albedo map (--albedo map)")
    auto = effects is None
    effects = () if auto else tuple(effects)
    if any(e != "frame_exposure" for e in effects) or len(effects) > 1:
        raise CtjaxError(
            f"effects {list(effects)}: the branch and bound fits frame_exposure only (a gain "
            "per frame); the other image effects with a near light: `ctjax calibrate-light "
            "--effects ...`"
        )
    if effects and albedo != "map":
        raise CtjaxError("frame_exposure is fitted with the albedo map (--albedo map)")
    obs = Observations.of(capture, masks)
    if albedo == "map":
        mapped = functools.partial(
            fit_albedo_map,
            obs,
            masks,
            family,
            tolerance=tolerance,
            max_points=max_points,
            right_views=right_views,
        )
        fit = mapped(frame_exposure=bool(effects))
        if auto:
            fit = with_exposure_where_needed(fit, lambda: mapped(frame_exposure=True))
    else:
        fit = fit_uniform(obs, masks, family, tolerance=tolerance)
    estimate = flag_misoriented(fit, obs.capture, obs.sets)
    if unmapped is not None:
        estimate.warnings.insert(0, unmapped)
    return estimate


def with_exposure_where_needed(fit: Estimate, with_exposure) -> Estimate:
    """`fit` (one exposure for every frame), or `with_exposure()` (the fit with a gain per
    frame) where `fit`'s frames are brighter or darker than the others predict and undoing
    that moves its lobe (`Status.brightness_off`, `judge_frames_brightness`): a scope's
    auto-exposure, which the lobe would otherwise absorb. `details["exposure"]` says which
    and why, with what the one exposure gave.

    Measured on a second real sinus video (24 frames of a turbinate, 640 px): one exposure
    gave sigma 0.239, `brightness_off`, and its even / odd frames 0.364 / 0.390; a gain per
    frame sigma 0.324 +- 0.002, `successful`, even / odd frames fitted apart 0.390 / 0.380
    (docs: real endoscopic video)."""
    off = [
        u for u in fit.details.get("undetermined", []) if u["status"] == Status.brightness_off.name
    ]
    if not off:
        if fit.details.get("albedo") == "map":
            fit.details["exposure"] = {
                "fitted": "one",
                "why": "the frames' brightness agrees with the fit, or the lobe does not "
                "absorb what differs",
            }
        return fit
    try:
        again = with_exposure()
    except CtjaxError as error:  # the flagged fit stands, and says why it was not redone
        fit.details["exposure"] = {"fitted": "one", "why": f"a gain per frame failed: {error}"}
        fit.warnings.append(f"a gain per frame (frame_exposure) could not be fitted: {error}")
        return fit
    one = fit.to_json()
    again.details["exposure"] = {
        "fitted": "per_frame",
        "why": off[0]["reason"],
        "one_exposure": {
            k: one.get(k)
            for k in ("status", "sigma", "F_tilde", "rgb_rmse", "brightness_off")
            if k in one
        },
    }
    return again
