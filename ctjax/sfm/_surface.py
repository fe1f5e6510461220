"""A dense smooth surface from sparse SfM points: a penalised B-spline depth map per view.

Why this surface model. The normals are what the BRDF and light estimates use, and a normal
is a derivative of depth: the error of a normal is the error of the surface's slope, so the
model must (i) average many points for each slope, (ii) bend only as much as the data
demand, and (iii) give the slope analytically. A tensor-product cubic B-spline depth map
z(u, v) over a view's pixel grid, with a dense knot grid and a curvature penalty (P-spline:
second differences of the coefficients in u, v and the cross term, a discrete thin-plate
energy), does all three: it is linear in its coefficients, so every point of every frame is
used at once in one least-squares solve; its smoothness is set by the data, by cross-validation
on held-out blocks of points rather than by hand; it is C2, so normals come from the exact
derivatives (z_u, z_v) of the fitted spline, not from finite differences of a noisy depth
map; and a robust reweighting (Tukey's biweight on the depth residuals) removes the few
mismatched points. A thin-plate spline interpolating or lightly smoothing the points, by
contrast, follows each point's noise and its slopes between close points are poor.

Geometry: pixel (u, v) with ctjax's convention (centre of pixel (i, j) at u = j, v = i); the
camera-frame point is P = z ((u - cx)/fx, (v - cy)/fy, 1) and the normal is P_v x P_u,
oriented towards the camera, as `ctjax._geometry.normals_from_depth` does.
"""

import dataclasses

import numpy as np
import scipy.linalg
import scipy.sparse

from .._camera import Camera

_TUKEY_C = 4.685
_SMOOTHING_GRID = np.logspace(-2, 2, 9)
_INITIAL_SMOOTHING = 1.0
_FOLDS = 5
# The most coefficients a view's surface may have: its normal equations and penalty are dense
# (coefficients^2 float64 each, 134 MB at 4096, with a few copies while they are built). At
# 640x512 it allows knots every 10 px (default 32).
MAX_SURFACE_COEFFICIENTS = 4096


def _cubic_weights(f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform cubic B-spline weights of the 4 active basis functions at fraction f in [0, 1],
    and their first and second derivatives with respect to f."""
    g = 1 - f
    w = np.stack([g**3, 3 * f**3 - 6 * f**2 + 4, -3 * f**3 + 3 * f**2 + 3 * f + 1, f**3], -1) / 6
    dw = np.stack([-(g**2), 3 * f**2 - 4 * f, -3 * f**2 + 2 * f + 1, f**2], -1) / 2
    d2w = np.stack([g, 3 * f - 2, -3 * f + 1, f], -1)
    return w, dw, d2w


@dataclasses.dataclass(frozen=True)
class _Axis:
    """Uniform cubic B-spline basis along one image axis: `count` functions on [lo, hi]."""

    lo: float
    spacing: float
    count: int

    @classmethod
    def covering(cls, lo: float, hi: float, spacing: float) -> "_Axis":
        intervals = max(1, int(np.ceil((hi - lo) / spacing)))
        return cls(lo, (hi - lo) / intervals, intervals + 3)

    def locate(self, x: np.ndarray):
        t = (np.asarray(x, np.float64) - self.lo) / self.spacing
        first = np.clip(np.floor(t), 0, self.count - 4).astype(np.int64)
        w, dw, _ = _cubic_weights(t - first)
        return first, w, dw / self.spacing

    def difference_penalty(self, order: int) -> np.ndarray:
        d = np.diff(np.eye(self.count), n=order, axis=0)
        return d.T @ d


@dataclasses.dataclass(frozen=True)
class DepthSurface:
    """A fitted depth map z(u, v) of one view (same length unit as the points it was fitted
    to): cubic B-spline coefficients on a uniform knot grid over the pixel plane."""

    u_axis: _Axis
    v_axis: _Axis
    coefficients: np.ndarray  # (v_axis.count, u_axis.count)
    smoothing: float  # cross-validated penalty weight (relative to the data term)
    inliers: np.ndarray  # (N,) bool: points kept by the robust reweighting
    residual_rms: float  # of the inliers, length unit of the points
    # The points it was fitted to: pixels u, v (N,), depth z (N,), robust weights (N,).
    points: tuple | None = None

    def depth_and_gradient(self, u: np.ndarray, v: np.ndarray):
        """z, dz/du, dz/dv at pixel positions (any matching shapes)."""
        iu, wu, dwu = self.u_axis.locate(np.ravel(u))
        iv, wv, dwv = self.v_axis.locate(np.ravel(v))
        rows = iv[:, None] + np.arange(4)
        cols = iu[:, None] + np.arange(4)
        patch = self.coefficients[rows[:, :, None], cols[:, None, :]]  # (N, 4, 4)
        z = np.einsum("na,nab,nb->n", wv, patch, wu)
        zu = np.einsum("na,nab,nb->n", wv, patch, dwu)
        zv = np.einsum("na,nab,nb->n", dwv, patch, wu)
        shape = np.shape(u)
        return z.reshape(shape), zu.reshape(shape), zv.reshape(shape)

    def geometry(self, camera: Camera, u: np.ndarray, v: np.ndarray):
        """Depth and unit camera-frame normals (facing the camera) at pixel positions."""
        z, zu, zv = self.depth_and_gradient(u, v)
        a = (u - float(camera.cx)) / float(camera.fx)
        b = (v - float(camera.cy)) / float(camera.fy)
        ray = np.stack([a, b, np.ones_like(a)], axis=-1)
        p_u = zu[..., None] * ray + np.stack([z / float(camera.fx), 0 * z, 0 * z], axis=-1)
        p_v = zv[..., None] * ray + np.stack([0 * z, z / float(camera.fy), 0 * z], axis=-1)
        normal = np.cross(p_v, p_u)
        norm = np.linalg.norm(normal, axis=-1, keepdims=True)
        ok = (norm[..., 0] > 0) & (z > 0)
        normal = normal / np.where(norm > 0, norm, 1)
        normal = np.where((np.sum(normal * ray, axis=-1) > 0)[..., None], -normal, normal)
        normal[~ok] = np.nan
        return np.where(ok, z, np.nan), normal


def surface_coefficients(width: float, height: float, knot_spacing_px: float) -> int:
    """How many coefficients a surface over a `width` x `height` px rectangle has."""
    u_axis = _Axis.covering(0.0, float(width), knot_spacing_px)
    v_axis = _Axis.covering(0.0, float(height), knot_spacing_px)
    return u_axis.count * v_axis.count


def fit_depth_surface(
    u: np.ndarray,
    v: np.ndarray,
    z: np.ndarray,
    bounds: tuple[float, float, float, float],
    *,
    knot_spacing_px: float,
    robust_iterations: int = 3,
) -> DepthSurface:
    """Fit z(u, v) to points seen at pixels (u, v) with depth z.

    `bounds` = (u_lo, u_hi, v_lo, v_hi), the pixel rectangle the spline covers. The points
    are reweighted by Tukey's biweight of their residuals (scale: 1.4826 MAD)
    `robust_iterations` times under a firm penalty; then the penalty weight (relative to
    the data term) is chosen by block cross-validation on the inliers, and the fit is
    reweighted once more and repeated.
    """
    u_axis = _Axis.covering(bounds[0], bounds[1], knot_spacing_px)
    v_axis = _Axis.covering(bounds[2], bounds[3], knot_spacing_px)
    n = len(z)
    design = design_matrix(u_axis, v_axis, u, v)
    penalty = thin_plate_penalty(u_axis, v_axis)
    # Blocks of two knots; four along the longer side where two knots span it all (one block
    # was one fold holding out every point, and its solve failed).
    extent = max(bounds[1] - bounds[0], bounds[3] - bounds[2])
    block = 2 * knot_spacing_px if 2 * knot_spacing_px < extent else extent / 4
    blocks = _blocks(u, v, block)
    weights = np.ones(n)
    smoothing = _INITIAL_SMOOTHING
    for iteration in range(robust_iterations + 2):
        if iteration == robust_iterations:
            # Outliers are down-weighted by now: choose the smoothing on the inliers.
            smoothing = _cross_validated_smoothing(design, penalty, z, weights, blocks)
        coefficients = _solve(design, penalty, z, weights, smoothing)
        residual = z - design @ coefficients
        weights = _tukey_weights(residual, weights, z)
    inliers = weights > 0
    rms = float(np.sqrt(np.mean(residual[inliers] ** 2))) if inliers.any() else float("nan")
    coefficients = coefficients.reshape(v_axis.count, u_axis.count)
    points = (np.asarray(u, float), np.asarray(v, float), np.asarray(z, float), weights)
    return DepthSurface(u_axis, v_axis, coefficients, smoothing, inliers, rms, points)


def design_matrix(u_axis: _Axis, v_axis: _Axis, u: np.ndarray, v: np.ndarray):
    """The spline's values at pixels (u, v) as a sparse (N, coefficients) matrix: z = B c,
    with c the coefficients (v_axis.count, u_axis.count) flattened row by row."""
    nu, nv = u_axis.count, v_axis.count
    iu, wu, _ = u_axis.locate(u)
    iv, wv, _ = v_axis.locate(v)
    n = len(u)
    rows = np.repeat(np.arange(n), 16)
    cols = (iv[:, None, None] + np.arange(4)[:, None]) * nu + iu[:, None, None] + np.arange(4)
    values = wv[:, :, None] * wu[:, None, :]
    return scipy.sparse.csr_matrix((values.ravel(), (rows, cols.ravel())), shape=(n, nu * nv))


def thin_plate_penalty(u_axis: _Axis, v_axis: _Axis) -> np.ndarray:
    """Second differences of the coefficients in u, in v and across (a discrete thin-plate
    energy c^T P c)."""
    eye_u, eye_v = np.eye(u_axis.count), np.eye(v_axis.count)
    return (
        np.kron(eye_v, u_axis.difference_penalty(2))
        + np.kron(v_axis.difference_penalty(2), eye_u)
        + 2 * np.kron(v_axis.difference_penalty(1), u_axis.difference_penalty(1))
    )


def _tukey_weights(residual, weights, z):
    kept = weights > 0
    scale = 1.4826 * np.median(np.abs(residual[kept] - np.median(residual[kept])))
    scale = max(scale, 1e-12 * max(float(np.median(np.abs(z))), 1e-300))
    r = residual / (_TUKEY_C * scale)
    return np.where(np.abs(r) < 1, (1 - r**2) ** 2, 0.0)


def _blocks(u, v, size):
    """Fold of each point for cross-validation: square blocks of `size` px, shuffled."""
    bu = np.floor((u - u.min()) / size).astype(np.int64)
    bv = np.floor((v - v.min()) / size).astype(np.int64)
    block = bv * (bu.max() + 1) + bu
    order = np.random.default_rng(0).permutation(block.max() + 1)
    return order[block] % _FOLDS


def _system(design, penalty, weights):
    normal = (design.T @ design.multiply(weights[:, None]).tocsr()).toarray()
    # Penalty weights relative to the data term, so one grid fits any point count and unit.
    relative = np.trace(normal) / max(np.trace(penalty), 1e-300)
    ridge = 1e-9 * np.trace(normal) / len(normal) * np.eye(len(normal))
    return normal + ridge, relative * penalty


def _solve(design, penalty, z, weights, smoothing):
    normal, scaled_penalty = _system(design, penalty, weights)
    return solve_banded(normal + smoothing * scaled_penalty, design.T @ (weights * z))


def solve_banded(system: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve a symmetric positive definite system that is banded (B-spline normal
    equations couple coefficients up to 3 knot rows apart): O(n b^2), not O(n^3)."""
    # The band: in each row, how far left of the diagonal its first nonzero lies (symmetric:
    # the same to the right). 20x faster than np.nonzero's index arrays, which took 12% of
    # a small reconstruction.
    n = len(system)
    nonzero = system != 0
    first = np.argmax(nonzero, axis=1)
    band = int(np.max(np.where(nonzero.any(axis=1), np.arange(n) - first, 0), initial=0))
    banded = np.zeros((band + 1, n))
    for k in range(band + 1):
        banded[band - k, k:] = np.diagonal(system, k)
    try:
        return scipy.linalg.solveh_banded(banded, rhs, check_finite=False)
    except np.linalg.LinAlgError:
        # Numerically semi-definite: a penalty weight far above the data's (texture smoothing
        # 1e6), or knots so wide that held-out blocks leave coefficients unseen. The least-
        # squares solution (the penalty's limit: the smoothest surface) instead of a failure.
        return scipy.linalg.lstsq(system, rhs, check_finite=False)[0]


def _cross_validated_smoothing(design, penalty, z, weights, folds) -> float:
    """The penalty weight with the least weighted prediction error on held-out blocks.

    Blocks of neighbouring points are held out together: SfM points come in clusters (SIFT
    keeps several orientations of a keypoint, and neighbouring points share their errors),
    and leaving one point out at a time (or GCV) then rewards a surface that follows the
    clusters' noise; the normals pay for it.
    """
    _, scaled_penalty = _system(design, penalty, weights)
    errors = np.zeros(len(_SMOOTHING_GRID))
    for fold in range(_FOLDS):
        held = folds == fold
        if not np.any(held & (weights > 0)) or not np.any(~held & (weights > 0)):
            continue  # nothing to judge, or nothing left to fit
        train = np.where(held, 0.0, weights)
        normal, _ = _system(design, penalty, train)
        rhs = design.T @ (train * z)
        for k, smoothing in enumerate(_SMOOTHING_GRID):
            coefficients = solve_banded(normal + smoothing * scaled_penalty, rhs)
            residual = (z - design @ coefficients)[held]
            errors[k] += np.sum(weights[held] * residual**2)
    if not np.any(errors):  # no fold could be judged (a handful of points in one block)
        return _INITIAL_SMOOTHING
    return float(_SMOOTHING_GRID[int(np.argmin(errors))])
