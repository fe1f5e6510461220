"""`J^T J` of a tall Jacobian (many residuals, few parameters) from its columns taken
apart: the information matrix of the global fitters' standard errors.

Why not `jac.T @ jac`: where the product reads the (M, P) matrix straight from
`jax.jacfwd` in the same program, XLA:CPU compiles the batched forward pass into code that
runs about 5x slower (likely its layout, the parameters' axis innermost; not examined).
Taking the P columns apart first gives the same matrix (to the summation's rounding) from
the fast code. Measured on the standard errors of the near light's map fit
(`benchmarks/information_matrix.py`: a 12-frame capture, 16384 tracks, 590k residuals):
3.72 s -> 0.76 s with 14 parameters (sigma, a lens-plane offset, 11 frame exposures),
1.00 s -> 0.20 s with 3; the same matrices. The Levenberg-Marquardt loop's normal
equations (`DenseLM`, the Jacobian inside a `lax.cond`) run at the fast speed as they
are: taken apart there, the fits took as long as before.
"""

import jax.numpy as jnp

from .._typing import Array, Float


def gram(jacobian: Float[Array, "M P"]) -> Float[Array, "P P"]:
    """`J^T J` of the (M, P) `jacobian`: the information matrix of unit-variance residuals."""
    columns = jnp.stack([jacobian[:, i] for i in range(jacobian.shape[1])])  # (P, M)
    return columns @ columns.T
