"""`ctjax fit`: the BRDF of a capture, by the albedo map (`_map_fit.py`) or the paper's one
albedo (`_uniform_fit.py`)."""

from .._errors import CtjaxError
from .._result import Estimate
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


def fit_capture(
    capture: "Capture | Observations",
    masks: MaskOptions = DEFAULT_MASKS,
    family: BRDFFamily = PAPER,
    *,
    tolerance: float = 1e-3,
    albedo: str | None = None,
    max_points: int | None = None,
    right_views: bool = False,
) -> Estimate:
    """Estimate the BRDF of a capture: the paper's light (co-located with the camera,
    L = V) and its model (`family`) by default.

    `albedo="map"` (the default when every frame has depth and a pose, `default_albedo`):
    one rho_tilde per surface point and channel, with F_tilde and sigma shared, from all
    frames (`fit_albedo_map`): the estimate for textured tissue. `albedo="uniform"`: the
    paper's model, one rho_tilde, fitted on the ring S~ of every frame (below).
    `right_views`: with the map, a stereo capture's right images too (`fit_albedo_map`).
    Either way the estimate carries the highlights' alignment
    (`ctjax.specular.flag_misoriented`): where one rotation of the normals would put the
    highlights at N = H, the lobe is no measurement (`Status.misoriented`).
    """
    albedo = default_albedo(capture) if albedo is None else albedo
    if albedo not in ALBEDO_CHOICES:
        raise CtjaxError(f"albedo must be one of {ALBEDO_CHOICES}, got {albedo!r}")
    if right_views and albedo != "map":
        raise CtjaxError("the right views are fitted with the albedo map (--albedo map)")
    obs = Observations.of(capture, masks)
    if albedo == "map":
        fit = fit_albedo_map(
            obs,
            masks,
            family,
            tolerance=tolerance,
            max_points=max_points,
            right_views=right_views,
        )
    else:
        fit = fit_uniform(obs, masks, family, tolerance=tolerance)
    return flag_misoriented(fit, obs.capture, obs.sets)
