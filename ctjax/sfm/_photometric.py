"""Photometric refinement of the SfM surfaces: every pixel's texture, seen from several frames.

Why. The BRDF's lobe is read at the highlights' rim, from the angle between each pixel's
normal and the light, so an error of the normal there is an error of the lobe: on the
default demo capture, SfM's surfaces (1617 points, a keypoint per ~50 pixels, 0.3-0.5 mm of
depth noise at 70 mm, none under the masked highlights) err by 2.2 degrees (median) and by
6.5 degrees (90th percentile) around the highlights, and the BRDF fitted on them had
sigma +24.5% and F_tilde -50%, against +0.1% and -0.3% with the true normals (SfM's depth and
poses were as good as the truth: `benchmarks/sfm_bias.py`).

What. The points are few, the pixels are many: each view's depth spline z(u, v) (the same
P-spline basis, `_surface.py`) is refined so that its surface points, carried into the
other frames by the SfM poses, land on the same texture. Gauss-Newton on

    sum over pixels p of the view, over pairs (m, k) of frames that see p's point unmasked,
    of  cauchy(T_m(pi_m(z(p))) - T_k(pi_k(z(p))))  +  smoothing * thin-plate energy(c),

with T the high-pass of the log image per channel (log turns albedo times shading into a
sum; subtracting a 1.5 px blur removes the shading, which changes from view to view, and
keeps the texture's detail, which does not) and pi_m the projection into frame m, plus the
SfM points' squared depth residuals (weight `POINTS_WEIGHT`). The view itself is one of the
frames, but a pixel under its own highlight is still refined from the frames where the same
point is not (the light moves with the camera). Highlights (S and clipped pixels, dilated by
8 px: the specular rim is not multiplicative and does move) and pixels outside the field of
view are masked in every frame. Each pixel's residuals depend on its depth alone, so the
normal equations are those of the P-spline, banded.

Measured (docs, "Shape from images"): on the demo capture (320x256, 5 frames, texture
30%) normals' median error 1.5 -> 0.6 degrees, the BRDF fitted on them sigma +9.5% ->
+4.4%, F_tilde -24% -> -2..0%; at 640x512 x 8 sigma +4.1%, F_tilde -4.9..-3.3%. Elsewhere
the error of the BRDF from images stays 5-30% in F_tilde: with the highlight's core clipped
the lobe is read on its tails, where a degree of normal error changes the specular by about
20%, and the texture does not pin the slopes below a degree. A texture smooth at the pixel
scale (tests/independent.py) does not pin them at all: its high-pass is noise, and the
refinement leaves SfM's surface where it is. Each view is refined alone, so `reconstruct`
keeps the refined views only where the frames' surfaces still agree (`_agreement.py`: on
the shared real videos they did not).
"""

import dataclasses
import math

import cv2
import numpy as np

from .._camera import Camera
from .._tracks import sample_image
from ._colmap import highlight_mask
from ._surface import DepthSurface, design_matrix, solve_banded, thin_plate_penalty

# The blur (px) whose removal from the log image leaves the texture (1-2 px worked alike;
# 3 px kept enough of the shading and the specular rim to bias the slopes, 6 px failed).
HIGH_PASS_PX = 1.5
# Highlights are masked with this margin (px): 3 px left the specular rim in, and the BRDF
# fitted on the result was 10-20% off; 14 px left the rim too few pixels.
MASK_DILATE_PX = 8
# Thin-plate penalty weight relative to the data's (as `fit_depth_surface` scales it), the
# default of `reconstruct(texture_smoothing=)`. Chosen before the SfM points anchored the
# refinement (then 2-3 followed the noise, 20 and more flattened the bumps). Measured again
# with the points (docs: reconstruct, "The texture refinement's smoothing"): 2 gives better
# normals and sigma on 4 synthetic captures (640x512 x 8: sigma +5.8% -> +2.1%), F_tilde
# better on 2 and worse on 2 (-8.6% -> -24.5%), the cholecystectomy video's frames agree
# better (6.3 -> 5.2 degrees), the sinus video's less (8.2 -> 9.7; its RMSE +12%): kept.
SMOOTHING = 5.0
# The SfM points' weight beside the texture's (0: the texture alone). Above 1 because the
# texture's residuals are correlated (neighbouring pixels share the 1.5 px high-pass, a view's
# partners share its pixels) and so count many times over. Measured with `ctjax synth`
# captures reconstructed then fitted (sigma / worst F_tilde error): 640x512 x 8 +7.1/-14.7%
# (0), +4.1/-4.9% (10), +3.4/+2.1% (30); 1080p x 10 median normal error 0.86 deg (1) -> 0.61
# (10); at 320x256 x 5 mixed over 5 seeds (noise dominates); 100 flattened the bumps.
POINTS_WEIGHT = 10.0
ITERATIONS = 3
# Frames a view is compared with besides itself: the nearest in camera position.
PARTNERS = 4
# Pixels used per view (every k-th above it). The noise limits the slopes: a quarter of
# the demo's pixels left sigma +6.3% where all of them give +4.4%.
MAX_PIXELS = 250_000
# Cauchy scale, in robust standard deviations of the texture residuals (occlusions,
# unmasked specular and moving overlays are down-weighted).
_CAUCHY = 3.0


@dataclasses.dataclass(frozen=True)
class Texture:
    """A frame's texture (high-pass log image, (H, W, 3) float32), its gradients in u and v,
    and where it is usable (float32 1/0: not a highlight, inside the field of view)."""

    value: np.ndarray
    du: np.ndarray
    dv: np.ndarray
    usable: np.ndarray

    @classmethod
    def of(cls, image: np.ndarray, visible: np.ndarray) -> "Texture":
        log = np.log(np.clip(np.asarray(image, np.float64), 1 / 255, None))
        value = log - cv2.GaussianBlur(log, (0, 0), HIGH_PASS_PX)
        du = cv2.Sobel(value, cv2.CV_64F, 1, 0, ksize=1) / 2
        dv = cv2.Sobel(value, cv2.CV_64F, 0, 1, ksize=1) / 2
        usable = ~highlight_mask(image, MASK_DILATE_PX) & visible
        as32 = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
        return cls(as32(value), as32(du), as32(dv), as32(usable))


@dataclasses.dataclass(frozen=True)
class Refinement:
    """A refined surface and what the refinement did: the texture residuals' mean Cauchy
    loss before and after (its scale: 3 robust standard deviations of the residuals of
    the surface fitted to the points, in which 1.0 is 1.7 such scales), the median
    |depth change| over the refined pixels (the surface's length unit) and the pixels used.
    `kept`: the refined surface lowered the loss and replaces the SfM one; else `surface`
    is the unrefined one (`residual_after` is then the lowest loss an iterate reached)."""

    surface: DepthSurface
    residual_before: float
    residual_after: float
    depth_change: float
    pixels: int
    kept: bool = True


PHOTOMETRIC_MODEL = (
    "each view's spline refined by Gauss-Newton so that its pixels' surface points land on "
    "the same texture (high-pass of the log image) in the nearest frames, highlights masked, "
    "while staying near its SfM points (weight points_weight beside the texture's)"
)


def _rays(camera: Camera, u, v) -> np.ndarray:
    return np.stack(
        [
            (u - float(camera.cx)) / float(camera.fx),
            (v - float(camera.cy)) / float(camera.fy),
            1 + 0 * u,
        ],
        axis=-1,
    )


def _sample(camera: Camera, points, rays, view_from_ref, texture: Texture):
    """The texture where `points` (reference camera frame) land in a view, its derivative
    with respect to the reference depth (points = depth * rays), and whether it counts."""
    rotation, shift = view_from_ref[:3, :3], view_from_ref[:3, 3]
    x = points @ rotation.T + shift
    dx = rays @ rotation.T  # d x / d depth
    z = np.where(x[:, 2] > 1e-9, x[:, 2], np.nan)
    u = float(camera.fx) * x[:, 0] / z + float(camera.cx)
    v = float(camera.fy) * x[:, 1] / z + float(camera.cy)
    du = float(camera.fx) * (dx[:, 0] * z - x[:, 0] * dx[:, 2]) / z**2
    dv = float(camera.fy) * (dx[:, 1] * z - x[:, 1] * dx[:, 2]) / z**2
    value = sample_image(texture.value, u, v)
    slope = (
        sample_image(texture.du, u, v) * du[:, None] + sample_image(texture.dv, u, v) * dv[:, None]
    )
    counts = (sample_image(texture.usable, u, v) > 0.999) & np.all(np.isfinite(value), -1)
    return np.where(counts[:, None], value, 0), np.where(counts[:, None], slope, 0), counts


def _pair_sums(samples):
    """Per pixel: every pair of views that both see it; returns the residuals and the
    depth derivatives of all pairs, stacked (pairs, N, 3), and which count (pairs, N)."""
    residual, slope, counts = [], [], []
    for i in range(len(samples)):
        for k in range(i + 1, len(samples)):
            (vi, si, ci), (vk, sk, ck) = samples[i], samples[k]
            both = ci & ck
            residual.append(np.where(both[:, None], vi - vk, 0))
            slope.append(np.where(both[:, None], si - sk, 0))
            counts.append(both)
    return np.stack(residual), np.stack(slope), np.stack(counts)


def _cauchy_cost(residual, counts, scale) -> float:
    """Mean Cauchy loss of the texture residuals that count (what Gauss-Newton lowers)."""
    loss = np.log1p((residual / (_CAUCHY * scale)) ** 2)
    return float(np.sum(loss * counts[..., None]) / max(3 * int(counts.sum()), 1))


def _robust_scale(residual, counts) -> float:
    values = np.abs(residual[counts])
    return float(1.4826 * np.median(values)) if values.size else 0.0


def refine_surface(
    surface: DepthSurface,
    hull: np.ndarray,
    camera: Camera,
    own: tuple[np.ndarray, Texture],
    partners: list[tuple[np.ndarray, Texture]],
    iterations: int = ITERATIONS,
    smoothing: float = SMOOTHING,
) -> Refinement:
    """Refine one view's depth spline by the texture's consistency (see the module doc).

    `own` and `partners`: (view_from_ref 4x4, Texture) of the view itself (identity) and of
    the frames it is compared with; `smoothing` the thin-plate penalty's weight relative to
    the data's. Returns the surface unchanged when no pixel is seen unmasked by two
    frames."""
    rows, cols = np.nonzero(hull)
    keep = np.arange(rows.size) % max(1, -(-rows.size // MAX_PIXELS)) == 0
    u, v = cols[keep].astype(np.float64), rows[keep].astype(np.float64)
    design = design_matrix(surface.u_axis, surface.v_axis, u, v)
    penalty = thin_plate_penalty(surface.u_axis, surface.v_axis)
    rays = _rays(camera, u, v)
    anchors = _point_equations(surface)
    start = surface.coefficients.ravel()
    coefficients, scale, before, after = start.copy(), None, math.nan, math.nan
    # The iterate of lowest loss is kept (Gauss-Newton on a robust loss may overshoot):
    # the start, unless a step lowered the loss.
    best, best_cost = start, math.inf
    for iteration in range(iterations + 1):
        depth = design @ coefficients
        points = depth[:, None] * rays
        samples = [_sample(camera, points, rays, pose, tex) for pose, tex in (own, *partners)]
        residual, slope, counts = _pair_sums(samples)
        if not counts.any():
            break
        scale = _robust_scale(residual, counts) if scale is None else scale
        if scale == 0:
            break
        cost = _cauchy_cost(residual, counts, scale)
        before = cost if iteration == 0 else before
        if cost < best_cost:
            best, best_cost = coefficients, cost
        after = cost
        if iteration == iterations:
            break
        weight = counts[..., None] / (1 + (residual / (_CAUCHY * scale)) ** 2) / scale**2
        hessian = np.sum(weight * slope * slope, axis=(0, 2))
        gradient = np.sum(weight * slope * residual, axis=(0, 2))
        coefficients = _gauss_newton_step(
            design, penalty, (hessian, gradient), coefficients, anchors, smoothing
        )
    kept = math.isfinite(best_cost) and best_cost < before
    coefficients = best if kept else start
    after = best_cost if math.isfinite(best_cost) else after
    refined = dataclasses.replace(
        surface, coefficients=coefficients.reshape(surface.coefficients.shape)
    )
    change = np.abs(design @ coefficients - design @ start)
    return Refinement(
        refined, before, after, float(np.median(change)) if change.size else 0.0, u.size, kept
    )


def _point_equations(surface: DepthSurface):
    """The SfM points' normal equations (D^T W D, D^T W z), each point weighted by its
    robust weight over the surface's residual variance: in the same chi-square units as
    the texture's, whose residuals are divided by their own robust scale. None when the
    surface keeps no points or `POINTS_WEIGHT` is 0."""
    if surface.points is None or POINTS_WEIGHT == 0 or not surface.residual_rms > 0:
        return None
    u, v, z, weight = surface.points
    design = design_matrix(surface.u_axis, surface.v_axis, u, v)
    w = POINTS_WEIGHT * weight / surface.residual_rms**2
    return (design.T @ design.multiply(w[:, None]).tocsr()).toarray(), design.T @ (w * z)


def _gauss_newton_step(design, penalty, texture, coefficients, anchors, smoothing):
    """The Gauss-Newton update of the spline's coefficients: minimise the linearised texture
    residuals (`texture`: per pixel, the Hessian and gradient of their loss in depth), the
    SfM points' (`anchors`) and the thin-plate energy (weight `smoothing` relative to the
    data's)."""
    hessian, gradient = texture
    normal = (design.T @ design.multiply(hessian[:, None]).tocsr()).toarray()
    rhs = normal @ coefficients - design.T @ gradient
    if anchors is not None:
        normal, rhs = normal + anchors[0], rhs + anchors[1]
    trace = np.trace(normal)
    if not trace > 0:
        return coefficients
    ridge = 1e-6 * trace / len(normal)
    system = normal + smoothing * trace / np.trace(penalty) * penalty + ridge * np.eye(len(normal))
    return solve_banded(system, rhs + ridge * coefficients)


def refine_views(
    camera: Camera, views: dict, frames, say=lambda message: None, smoothing: float = SMOOTHING
) -> tuple:
    """Every view's surface refined (see the module doc); `views` as `reconstruct_capture`
    builds them (name -> ViewSurface, camera-to-world poses), `frames` the capture's,
    `smoothing` as `refine_surface`. Returns (refined views, {name: Refinement})."""
    by_name = {f.name: f for f in frames}
    textures = {n: Texture.of(by_name[n].image, by_name[n].visible) for n in views}
    centres = {n: view.pose[:3, 3] for n, view in views.items()}
    refined, details = {}, {}
    for name, view in views.items():
        others = sorted(
            (n for n in views if n != name),
            key=lambda n: float(np.linalg.norm(centres[n] - centres[name])),
        )[:PARTNERS]
        partners = [(np.linalg.inv(views[n].pose) @ view.pose, textures[n]) for n in others]
        result = refine_surface(
            view.surface,
            view.hull,
            camera,
            (np.eye(4), textures[name]),
            partners,
            smoothing=smoothing,
        )
        losses = f"texture loss {result.residual_before:.4f} -> {result.residual_after:.4f}"
        say(
            f"surface of {name} refined by its texture in {len(others)} other frame(s): {losses}"
            if result.kept
            else f"surface of {name} kept as SfM gave it: its texture in {len(others)} other "
            f"frame(s) did not lower the loss ({result.residual_before:.4f} at the start)"
        )
        refined[name] = dataclasses.replace(view, surface=result.surface)
        details[name] = result
    return refined, details


def photometric_report(refinements, smoothing: float, agreement: dict | None = None) -> dict:
    """The texture refinement in `ctjax reconstruct`'s report (`surface.photometric`);
    `agreement`: whether the frames' surfaces still agree with it (`_agreement.py`)."""
    if refinements is None:
        return {"refined": False}
    number = lambda x: float(x) if np.isfinite(x) else None  # noqa: E731
    kept = agreement is None or agreement["kept"]
    return {
        "refined": kept,
        "frames_agreement": agreement,
        "model": PHOTOMETRIC_MODEL,
        "smoothing": smoothing,
        "points_weight": POINTS_WEIGHT,
        "texture_loss_per_frame": {
            n: {"before": number(r.residual_before), "after": number(r.residual_after)}
            for n, r in refinements.items()
        },
        # A frame's surface is replaced only where the refinement lowered its loss, and
        # none where the refinement costs the frames' agreement.
        "kept_per_frame": {n: r.kept and kept for n, r in refinements.items()},
        "kept_frames": sum(r.kept for r in refinements.values()) if kept else 0,
        "median_depth_change_per_frame": {n: r.depth_change for n, r in refinements.items()},
        "pixels_per_frame": {n: r.pixels for n, r in refinements.items()},
    }
