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
# Active sets whose (Jacobi-scaled, unit-diagonal) Gram matrix has a Cholesky pivot below
# this are treated as singular (columns collinear to ~1e-5 in angle).
_SINGULAR = 1e-10


def _active_sets(k: int) -> Float[Array, "S K"]:
    subsets = [s for r in range(1, k + 1) for s in itertools.combinations(range(k), r)]
    return jnp.array([[i in s for i in range(k)] for s in subsets], dtype=bool)


def _cholesky_solve(system, rhs):
    """Solve the small SPD `system` (K x K, K <= 4) by an unrolled Cholesky factorisation.

    Returns the solution and the smallest squared pivot (the singularity test). Unrolled
    scalar arithmetic, not `jnp.linalg.solve`: LAPACK-style LU on a 2x2 lowers to loops and
    scatters that cost more than the whole design matrix under `vmap`.
    """
    k = system.shape[0]
    factor = [[None] * k for _ in range(k)]
    smallest = jnp.asarray(jnp.inf, system.dtype)
    for j in range(k):
        pivot = system[j, j] - sum(factor[j][m] ** 2 for m in range(j))
        smallest = jnp.minimum(smallest, pivot)
        diagonal = jnp.sqrt(jnp.maximum(pivot, _SINGULAR))
        factor[j][j] = diagonal
        for i in range(j + 1, k):
            factor[i][j] = (
                system[i, j] - sum(factor[i][m] * factor[j][m] for m in range(j))
            ) / diagonal
    forward = []
    for i in range(k):
        forward.append((rhs[i] - sum(factor[i][m] * forward[m] for m in range(i))) / factor[i][i])
    solution = [None] * k
    for i in reversed(range(k)):
        solution[i] = (
            forward[i] - sum(factor[m][i] * solution[m] for m in range(i + 1, k))
        ) / factor[i][i]
    return jnp.stack(solution), smallest


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
        x, smallest_pivot = _cholesky_solve(system, jnp.where(active[:, None], scaled_rhs, 0))
        ok = ok & (smallest_pivot > _SINGULAR)
        x = jnp.where(active[:, None] & ok, x, 0)
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


def nnls_columns(
    columns: tuple[Float[Array, " N"], ...],
    values: Float[Array, "N C"],
) -> tuple[Float[Array, "K C"], Float[Array, ""]]:
    """Closed-form NNLS on a design given as K separate columns (K <= 4).

    The columns-as-a-tuple form is the fast one under `vmap` over nonlinear parameters:
    columns that do not depend on them (the Lambertian one) stay unbatched, so JAX computes
    their Gram entries and right-hand sides once, and every entry is a fused
    multiply-and-reduce rather than a skinny matrix product.

    The cost is the sum of squared residuals over all C columns of `values`, from the
    normal equations, `|y|^2 - 2 x.rhs + x^T gram x` (exact to ~1e-12 relative in float64).
    In float32 that shortcut loses ~3% to cancellation, so float32 inputs have their sums
    (the Gram entries, right-hand sides and `|y|^2`) accumulated in float64 when JAX has
    float64 (`jax_enable_x64`): the columns are computed and read in float32 (half the
    memory traffic), the sums and the K x K algebra are exact, and the estimate and cost
    come back in float32. Without float64, the residuals are formed explicitly (slower).
    """
    k = len(columns)
    wide = values.dtype == jnp.float64 or jax.config.jax_enable_x64
    if not wide:
        return _nnls_columns_narrow(columns, values)
    acc = jnp.float64

    def dot(a, b):
        return jnp.matmul(a, b, preferred_element_type=acc)

    gram = jnp.stack([jnp.stack([dot(columns[i], columns[j]) for j in range(k)]) for i in range(k)])
    rhs = jnp.stack([dot(column, values) for column in columns])
    x = nnls_normal_equations(gram, rhs)
    total = jnp.sum(jnp.square(values), dtype=acc)
    cost = total - 2 * jnp.sum(x * rhs) + jnp.einsum("kc,kl,lc->", x, gram, x)
    cost = jnp.maximum(cost, 0)
    cost = jnp.where(jnp.isfinite(cost), cost, jnp.inf)
    return x.astype(values.dtype), cost.astype(values.dtype)


def _nnls_columns_narrow(columns, values):
    """`nnls_columns` in float32 without float64: explicit residuals for the cost."""
    k = len(columns)
    gram = jnp.stack([jnp.stack([columns[i] @ columns[j] for j in range(k)]) for i in range(k)])
    rhs = jnp.stack([column @ values for column in columns])
    x = nnls_normal_equations(gram, rhs)
    residual = values - sum(x[i] * columns[i][:, None] for i in range(k))
    cost = jnp.sum(residual * residual)
    return x, jnp.where(jnp.isfinite(cost), cost, jnp.inf)


def nnls(design: Float[Array, "N K"], values: Float[Array, "N C"]):
    """Closed-form NNLS of `values` (one problem per column C) on `design` (N, K), K <= 4.

    Returns `(x (K, C), cost)`, `cost` the sum of squared residuals over all columns: finite
    or +inf. See `nnls_columns`.
    """
    return nnls_columns(tuple(design[:, i] for i in range(design.shape[1])), values)
