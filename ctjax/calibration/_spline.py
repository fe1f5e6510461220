"""The light field's smoothing (paper section 5): a least-squares cubic B-spline over the
image, with a small second-difference penalty that fills holes (pixels without data).

It is fitted to the three components of L - V, not to theta and phi (which wrap around and
are singular at phi = 0), and normalised after evaluation.
"""

import numpy as np


def _bspline_basis(count: int, intervals: int) -> np.ndarray:
    """Uniform cubic B-spline basis at pixel centres 0..count-1, (count, intervals + 3)."""
    x = np.arange(count) * intervals / max(count - 1, 1)
    cell = np.minimum(np.floor(x).astype(int), intervals - 1)
    t = x - cell
    weights = np.stack(
        [(1 - t) ** 3, 3 * t**3 - 6 * t**2 + 4, -3 * t**3 + 3 * t**2 + 3 * t + 1, t**3], -1
    )
    basis = np.zeros((count, intervals + 3))
    for k in range(4):
        basis[np.arange(count), cell + k] = weights[:, k] / 6
    return basis


def _second_difference(n: int) -> np.ndarray:
    d = np.zeros((max(n - 2, 0), n))
    for i in range(n - 2):
        d[i, i : i + 3] = (1, -2, 1)
    return d.T @ d


def fit_spline(
    values: np.ndarray, weight: np.ndarray, knot_px: float, smoothing: float = 1e-3
) -> np.ndarray:
    """Weighted least-squares tensor cubic B-spline of `values` (H, W, C) on a uniform knot
    grid of about `knot_px` pixels, evaluated at every pixel centre: (H, W, C).

    A second-difference penalty (`smoothing` times the mean weight per coefficient) keeps
    the coefficients determined where no pixel has data; it bends the fit very little
    where there are data.
    """
    height, width = weight.shape
    bu = _bspline_basis(width, max(1, round((width - 1) / knot_px)))
    bv = _bspline_basis(height, max(1, round((height - 1) / knot_px)))
    nu, nv = bu.shape[1], bv.shape[1]
    w = weight.astype(float)
    # Normal equations of the Kronecker design without forming it: (nv nu) x (nv nu).
    inner = np.einsum("ij,jc,jd->icd", w, bu, bu)
    gram = np.einsum("ia,ib,icd->acbd", bv, bv, inner).reshape(nv * nu, nv * nu)
    rhs = np.einsum("ia,ij,jc,ijk->ack", bv, w, bu, values).reshape(nv * nu, -1)
    penalty = np.kron(_second_difference(nv), np.eye(nu)) + np.kron(
        np.eye(nv), _second_difference(nu)
    )
    scale = smoothing * max(w.sum(), 1.0) / (nv * nu)
    ridge = 1e-9 * max(w.sum(), 1.0) / (nv * nu) * np.eye(nv * nu)
    coefficients = np.linalg.solve(gram + scale * penalty + ridge, rhs).reshape(nv, nu, -1)
    return np.einsum("ia,abk,jb->ijk", bv, coefficients, bu)


def spline_field(directions, view, weight, knot_px) -> np.ndarray:
    """The smooth unit field from per-pixel directions: a spline of L - V, plus V."""
    deviation = np.where(weight[..., None] > 0, directions - view, 0)
    field = view + fit_spline(deviation, weight, knot_px)
    return field / np.linalg.norm(field, axis=-1, keepdims=True)
