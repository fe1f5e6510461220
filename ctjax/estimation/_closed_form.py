"""Nonnegative least squares in closed form for a few weights (K <= 4), in JAX.

For a fixed value of the nonlinear parameters (sigma...), the paper's subproblem (6) is a
nonnegative least squares in the linear weights (rho_tilde, F_tilde per channel). With K
weights its solution is the unconstrained least-squares solution on one of the 2^K - 1
nonempty active sets (or 0): we solve every one exactly and keep the best feasible one.
For K = 2 this is "the 2x2 normal equations, else the better of the two clamped
single-variable solutions".

Guards: a column that underflowed to 0 (the Beckmann term for sigma below ~1e-3, also in
float64) or is collinear with others makes its active sets singular; those sets are skipped,
never turned into NaN. Every returned cost is finite or +inf.
"""

import itertools

import jax
import jax.numpy as jnp

from .._typing import Array, Float

# A column whose squared norm is below this fraction of the largest one carries no signal.
_NEGLIGIBLE_COLUMN = 1e-24
# Active sets whose (Jacobi-scaled) Gram matrix has a smaller determinant are singular.
_SINGULAR = 1e-10


def _active_sets(k: int) -> Float[Array, "S K"]:
    subsets = [s for r in range(1, k + 1) for s in itertools.combinations(range(k), r)]
    return jnp.array([[i in s for i in range(k)] for s in subsets], dtype=bool)


def nnls_normal_equations(
    gram: Float[Array, "K K"], rhs: Float[Array, "K C"]
) -> Float[Array, "K C"]:
    """argmin_{x >= 0} |A x - y|^2 per column of `rhs`, from `gram = A^T A`, `rhs = A^T y`.

    Exact for K <= 4 (active-set enumeration); the objective is compared through the
    normal equations, `-2 x.rhs + x^T gram x`, which is exact in exact arithmetic. Callers
    needing the cost itself in float32 should recompute it from residuals (cancellation).
    """
    k = gram.shape[0]
    if k > 4:
        raise ValueError(f"closed-form NNLS enumerates active sets for K <= 4, got K = {k}")
    diagonal = jnp.diagonal(gram)
    usable = diagonal > _NEGLIGIBLE_COLUMN * jnp.max(diagonal)
    # Jacobi scaling: unit diagonal, so the determinant test is scale-free.
    scale = jnp.where(usable, 1 / jnp.sqrt(jnp.where(usable, diagonal, 1)), 0)
    scaled_gram = gram * scale[:, None] * scale[None, :]
    scaled_rhs = rhs * scale[:, None]

    def solve(active):
        ok = jnp.all(usable | ~active)
        mask = active[:, None] & active[None, :]
        system = jnp.where(mask, scaled_gram, jnp.eye(k, dtype=gram.dtype))
        determinant = jnp.linalg.det(system)
        ok = ok & (determinant > _SINGULAR)
        system = jnp.where(ok, system, jnp.eye(k, dtype=gram.dtype))
        x = jnp.linalg.solve(system, jnp.where(active[:, None], scaled_rhs, 0))
        x = jnp.where(active[:, None], x, 0)
        objective = -2 * jnp.sum(x * scaled_rhs, axis=0) + jnp.einsum(
            "kc,kl,lc->c", x, scaled_gram, x
        )
        feasible = ok & jnp.all(x >= 0, axis=0) & jnp.isfinite(objective)
        return x, jnp.where(feasible, objective, jnp.inf)

    xs, objectives = jax.vmap(solve)(_active_sets(k))  # (S, K, C), (S, C)
    best = jnp.argmin(objectives, axis=0)  # per channel
    x = jnp.take_along_axis(xs, best[None, None, :], axis=0)[0]
    # The empty set (x = 0, objective 0) wins when nothing else is feasible and better.
    x = jnp.where(jnp.min(objectives, axis=0) < 0, x, 0)
    return x * scale[:, None]


def nnls(design: Float[Array, "N K"], values: Float[Array, "N C"], weights=None):
    """Closed-form NNLS of `values` (one problem per column C) on `design`; K <= 4.

    Returns `(x (K, C), cost)` with `cost` the sum of squared residuals over all columns,
    computed from the residuals (not the normal equations) so that it is accurate in
    float32 too; `weights` (N,) optionally weighs the samples. Finite or +inf.
    """
    if weights is not None:
        root = jnp.sqrt(weights)[:, None]
        design, values = design * root, values * root
    x = nnls_normal_equations(design.T @ design, design.T @ values)
    residual = values - design @ x
    cost = jnp.sum(residual * residual)
    return x, jnp.where(jnp.isfinite(cost), cost, jnp.inf)
