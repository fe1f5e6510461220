"""What a model's residual is made of, where no candidate effect explains it.

On real video the diagnose loop can end with "none" far above the noise floor (the shared
sinus: 8.9x, the cholecystectomy video: 9.9x): what is left is not something a reflectance
or light candidate takes. Three parts are measured on the held-out pixels:

- **Misregistration**: a pixel whose surface point is misplaced by a displacement d (depth,
  poses, tissue that moved) reads the texture at the wrong place, and its residual is about
  grad I . d. For displacements of variance s^2 per axis, E[r^2] = a + s^2 |grad I|^2: the
  slope of the squared residual against the squared image gradient (least squares, away
  from the highlights and the field's edges) estimates s in pixels, and s^2 mean |grad I|^2
  is the share of the mean squared residual it accounts for.
- **Highlights**: the share of the squared residual within `NEAR_HIGHLIGHT_PX` of S (clipped
  cores, sparkles finer than the shape), beside the share of the pixels there, and how much
  brighter than the model they are, by the angle between the model's N and H
  (`ANGLE_BINS_DEG`): a lobe about these normals puts its light where that angle is small,
  so an excess that does not fall with it is light no such lobe can place (highlights where
  the shape's normals do not put them: facets finer than the shape, a misoriented surface).
- **Per frame**: the share a gain of each frame's own (exposure, a light that changed, tissue
  that moved as a whole) takes: per frame and channel, the residual's least-squares
  multiple of the predicted intensity.
- **Smooth in one variable**: for each physical variable (`VARIABLES`), the share its bin
  means take (what any effect that is a function of that variable alone could still
  remove): small shares say the candidates have not missed an angular or radial trend.

The parts overlap (a highlight has a strong gradient too; the misregistration's pixels are
taken away from the highlights) and do not sum to one; the rest is noise and what none of
them describes.
"""

import dataclasses
import itertools

import numpy as np

from .._units import METRIC, length_unit_of
from .._vector import Vec3
from ..observations import Observations
from ._variables import VARIABLES, physical_variables, variable_label

# "Near a highlight": within this many pixels of S (the evaluation's bound).
NEAR_HIGHLIGHT_PX = 7
# The near-S excess is also reported in these bins of the angle between N and H (degrees).
ANGLE_BINS_DEG = (0.0, 10.0, 20.0, 30.0, 45.0, 180.0)


def _angle_label(low: float, high: float) -> str:
    return f"{low:g}+" if high >= 180 else f"{low:g}-{high:g}"


@dataclasses.dataclass(frozen=True)
class ResidualBudget:
    """The parts of a model's held-out residual (see the module doc); shares of the mean
    squared residual (8-bit levels) over `samples` pixels."""

    rmse: float
    misregistration_px: float
    gradient_share: float
    highlight_share: float
    highlight_pixels: float
    highlight_excess: float
    per_frame_share: float
    smooth_share: dict[str, float]
    samples: int
    # Per bin of the angle between N and H (`ANGLE_BINS_DEG`, degrees): the near-S views'
    # mean excess (levels, None without views there) and their share of all the views.
    highlight_excess_by_angle: dict[str, tuple[float | None, float]] = dataclasses.field(
        default_factory=dict
    )
    # The capture's (`ctjax._units`): the distance to the light's unit in `summary`.
    length_unit: str = METRIC

    def to_json(self) -> dict:
        return {
            "rmse_levels": self.rmse,
            "misregistration_px": self.misregistration_px,
            "gradient_share": self.gradient_share,
            "highlight_share": self.highlight_share,
            "highlight_pixels": self.highlight_pixels,
            "highlight_excess_levels": self.highlight_excess,
            "highlight_excess_by_angle": {
                label: {"excess_levels": excess, "views": views}
                for label, (excess, views) in self.highlight_excess_by_angle.items()
            },
            "per_frame_share": self.per_frame_share,
            "smooth_share": dict(self.smooth_share),
            "samples": self.samples,
            "note": "shares of the held-out mean squared residual (under the map every "
            "held-out view of a tracked point predicted from its other views, as the held-out "
            "RMSE): the part that grows with the image gradient squared (a misregistration of "
            "misregistration_px pixels RMS per axis: shape, poses or tissue motion), the part "
            f"within {NEAR_HIGHLIGHT_PX} px of S (on highlight_pixels of the views; "
            "highlight_excess_levels: how much brighter than the model they are on average; "
            "highlight_excess_by_angle: the same by the angle between N and H, in degrees, "
            "with their share of the views: a lobe about the model's normals puts its light "
            "where that angle is small), what a gain per frame takes, and what a function "
            "of each physical variable alone takes; they overlap",
        }

    def summary(self) -> str:
        variable, smooth = max(self.smooth_share.items(), key=lambda item: item[1])
        return (
            f"residual {self.rmse:.2f} levels RMS: "
            f"{100 * self.gradient_share:.0f}% grows with the image gradient (about "
            f"{self.misregistration_px:.2f} px of misregistration: shape, poses or tissue "
            f"motion), {100 * self.highlight_share:.0f}% within {NEAR_HIGHLIGHT_PX} px of the "
            f"highlights ({100 * self.highlight_pixels:.0f}% of the pixels, "
            f"{self.highlight_excess:+.1f} levels against the model"
            f"{excess_by_angle_text(self.to_json()['highlight_excess_by_angle'])}), "
            f"{100 * self.per_frame_share:.0f}% a gain per frame, at most {100 * smooth:.0f}% "
            f"a function of one physical variable ({variable_label(variable, self.length_unit)})"
        )


def excess_by_angle_text(by_angle: dict) -> str:
    """`highlight_excess_by_angle` (the JSON's) for a line: "; by the angle between N and H:
    +12.3 at 0-10 deg, ..." (empty without views near S)."""
    parts = [
        f"{block['excess_levels']:+.1f} at {label} deg"
        for label, block in by_angle.items()
        if block["excess_levels"] is not None
    ]
    return f"; by the angle between N and H: {', '.join(parts)}" if parts else ""


def _gradient_squared(image: np.ndarray) -> np.ndarray:
    """(H, W): mean over channels of |grad I|^2, I in 8-bit levels (central differences)."""
    levels = 255.0 * np.asarray(image, np.float64)
    gy, gx = np.gradient(levels, axis=(0, 1))
    return np.mean(gx * gx + gy * gy, axis=-1)


def _inner(usable: np.ndarray) -> np.ndarray:
    """Usable pixels whose four neighbours are usable too (their gradient is the scene's,
    not the edge of the field of view or of the geometry)."""
    inner = usable.copy()
    inner[1:] &= usable[:-1]
    inner[:-1] &= usable[1:]
    inner[:, 1:] &= usable[:, :-1]
    inner[:, :-1] &= usable[:, 1:]
    inner[[0, -1]] = False
    inner[:, [0, -1]] = False
    return inner


def residual_budget(
    capture, frames, model, *, albedo: str = "map", max_samples: int = 40_000, seed: int = 2
) -> ResidualBudget:
    """The parts of `model`'s residual over pixels of `frames` (see the module doc). With
    `albedo="map"` each pixel's albedo comes from the other frames that see it (the residual
    maps' residual); `"uniform"`: the model's one rho_tilde. `heldout_budget` gives the
    parts of the residual a diagnosis reports."""
    from ._plots import pixel_residuals

    observations = Observations.of(capture)
    samples = observations.pixels(frames, max_samples=max_samples, seed=seed)
    residual = pixel_residuals(observations.capture, frames, model, samples, albedo)
    known = np.all(np.isfinite(residual), axis=1)
    measured_minus_model = np.where(known[:, None], -residual, 0)
    return _budget(observations, model, samples, measured_minus_model, known)


def heldout_budget(heldout, model) -> ResidualBudget:
    """The parts of `model`'s residual on a diagnosis's held-out data (`Diagnosis.heldout`):
    under the map (`HeldOutTracks`) every held-out view of a tracked point predicted from
    the point's other views, each weighted as in `heldout_rmse` (the RMSE this budget
    divides is the diagnosis's); else (`HeldOut`) its held-out pixels with the model's one
    albedo."""
    from ..heldout import HeldOutTracks

    if not isinstance(heldout, HeldOutTracks):
        return residual_budget(heldout.capture, heldout.heldout, model, albedo="uniform")
    from ..fitting._map_least_squares import heldout_map_residuals
    from ..observations import PixelSamples

    model = heldout.with_heldout_frames(model)
    test = heldout.test
    residual, weight = heldout_map_residuals(model, test, heldout.judged)
    kept = weight > 0  # (M, P)
    m, p = kept.shape

    def at_views(leaf):  # a corner array (4 M P): its bilinear mean per view, kept views
        corners = np.asarray(leaf).reshape(4, m, p)
        return np.sum(np.asarray(test.corner_weight) * corners, axis=0)[kept]

    point = np.stack([at_views(c) for c in (test.point.x, test.point.y, test.point.z)], -1)
    normal = np.stack([at_views(c) for c in (test.normal.x, test.normal.y, test.normal.z)], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    u, v = (np.asarray(a)[kept] for a in test.site.pixel)
    samples = PixelSamples(
        Vec3.from_array(point),
        Vec3.from_array(normal),
        (u, v),
        np.asarray(test.values)[:, kept].T,
        np.asarray(test.site.frame)[kept],
        np.rint(v).astype(int),
        np.rint(u).astype(int),
    )
    observations = Observations.of(heldout.capture)
    return _budget(observations, model, samples, residual[:, kept].T, weight[kept])


def _weighted_bins(x, residual, weight, bins: int = 16):
    """Per quantile bin of `x`: the weighted mean residual (bins, C) and the bin's weight."""
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    index = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    total = np.bincount(index, weight, len(edges) - 1)
    means = (
        np.stack([np.bincount(index, weight * r, len(edges) - 1) for r in residual.T], axis=1)
        / np.maximum(total, 1e-300)[:, None]
    )
    return means, total


def _budget(observations, model, samples, residual, weight) -> ResidualBudget:
    """The budget of `residual` (N, 3 levels, measured - predicted; 0 where `weight` is 0)
    at `samples`."""
    weight = np.asarray(weight, np.float64)
    known = weight > 0
    if known.sum() < 10:
        raise ValueError("fewer than 10 held-out observations with a residual: no budget")
    frame, row, col = (np.asarray(a) for a in (samples.frame, samples.row, samples.col))
    camera = observations.capture.camera
    row = np.clip(row, 0, camera.height - 1)
    col = np.clip(col, 0, camera.width - 1)
    gradient = np.full(len(frame), np.nan)
    near = np.zeros(len(frame), bool)
    for index in dict.fromkeys(frame[known].tolist()):
        here = frame == index
        squared = _gradient_squared(observations.capture.frames[index].image)
        inner = _inner(observations.usable[index])
        gradient[here] = np.where(inner, squared, np.nan)[row[here], col[here]]
        distance = observations.specular_distance(index)
        near[here] = distance[row[here], col[here]] <= NEAR_HIGHLIGHT_PX
    w = np.where(known, weight, 0.0)
    mean = lambda values, where=known: float(  # noqa: E731
        np.sum(w[where] * values[where]) / np.sum(w[where])
    )
    squared = np.mean(residual * residual, axis=1)
    total = mean(squared)
    variables = physical_variables(model, samples, camera)
    # A gain per frame: per frame and channel, the least-squares multiple of the prediction.
    predicted = np.asarray(variables["predicted"])
    degained = np.array(residual, np.float64)
    for index in dict.fromkeys(frame[known].tolist()):
        here = known & (frame == index)
        pw = predicted[here] * w[here]
        if pw @ predicted[here] > 0:
            degained[here] -= predicted[here, None] * (pw @ residual[here]) / (pw @ predicted[here])
    kept = np.mean(degained * degained, axis=1)
    per_frame = 1 - mean(kept) / total
    # Misregistration: r^2 = a + s^2 g^2 away from the highlights and the edges, on the
    # residual without its gain per frame (a gain's residual is brighter where the texture
    # is, and so steeper); weighted least squares.
    fit = known & ~near & np.isfinite(gradient)
    slope = 0.0
    if fit.sum() >= 10 and np.ptp(gradient[fit]) > 0:
        root = np.sqrt(w[fit])
        design = np.stack([root, root * gradient[fit]], axis=1)
        (_, slope), *_ = np.linalg.lstsq(design, root * kept[fit], rcond=None)
        slope = max(float(slope), 0.0)
    gradient_share = slope * mean(gradient, fit) / total if fit.any() else 0.0
    highlight_share = float(np.sum(w * squared * near) / np.sum(w * squared))
    angle = np.asarray(variables["angle_n_h_deg"])
    excess = np.mean(residual, axis=1)
    by_angle = {}
    for low, high in itertools.pairwise(ANGLE_BINS_DEG):
        here = known & near & (angle >= low) & (angle < high)
        by_angle[_angle_label(low, high)] = (
            mean(excess, here) if here.any() else None,
            mean(here.astype(float)),
        )
    smooth = {}
    for name in VARIABLES:
        means, bin_weight = _weighted_bins(
            np.asarray(variables[name])[known], residual[known], w[known]
        )
        explained = np.sum(bin_weight[:, None] * means * means) / 3 / np.sum(w[known])
        smooth[name] = float(explained / total)
    return ResidualBudget(
        rmse=float(np.sqrt(total)),
        misregistration_px=float(np.sqrt(slope)),
        gradient_share=float(min(gradient_share, 1.0)),
        highlight_share=highlight_share,
        highlight_pixels=mean(near.astype(float)),
        highlight_excess=(
            mean(np.mean(residual, axis=1), known & near) if (known & near).any() else 0.0
        ),
        per_frame_share=per_frame,
        smooth_share=smooth,
        samples=int(known.sum()),
        highlight_excess_by_angle=by_angle,
        length_unit=length_unit_of(observations),
    )
