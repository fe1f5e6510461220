"""Normals to depth: least-squares integration of log-depth gradients on the pixel grid."""

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as sparse_linalg

from .._errors import CtjaxError


def integrate_gradients(p: np.ndarray, q: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The log depth z (H, W) whose backward differences best match (p, q) in least squares
    (the discrete Poisson equation on the pixels of `mask`), NaN outside `mask`.

    `p[i, j] ~ z[i, j] - z[i, j-1]`, `q[i, j] ~ z[i, j] - z[i-1, j]` wherever both pixels are
    in `mask`. The solution is defined up to a constant per connected region: the mean of
    each region is set to 0 (a tiny ridge term), and scale is fixed later (known volume).
    """
    mask = np.asarray(mask, bool)
    count = int(mask.sum())
    if count < 2:
        raise CtjaxError(f"cannot integrate normals over {count} pixel(s)")
    if not (np.all(np.isfinite(p[mask])) and np.all(np.isfinite(q[mask]))):
        raise CtjaxError("cannot integrate normals: non-finite gradients inside the mask")
    index = np.full(mask.shape, -1, np.int64)
    index[mask] = np.arange(count)
    rows, cols, values, rhs = [], [], [], []
    equations = 0
    for both, here, before, gradient in (
        (mask[:, 1:] & mask[:, :-1], index[:, 1:], index[:, :-1], p[:, 1:]),
        (mask[1:, :] & mask[:-1, :], index[1:, :], index[:-1, :], q[1:, :]),
    ):
        n = int(both.sum())
        equation = np.arange(equations, equations + n)
        equations += n
        rows += [equation, equation]
        cols += [here[both], before[both]]
        values += [np.ones(n), -np.ones(n)]
        rhs.append(gradient[both])
    b = np.concatenate(rhs)
    a = sparse.csr_matrix(
        (np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
        shape=(b.size, count),
    )
    # Normal equations (a graph Laplacian) with a ridge far below the data's scale: it only
    # pins the free constant of each connected region (to its mean, 0).
    system = (a.T @ a + 1e-10 * sparse.identity(count)).tocsc()
    z = sparse_linalg.spsolve(system, a.T @ b)
    out = np.full(mask.shape, np.nan)
    out[mask] = z
    return out
