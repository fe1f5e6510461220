"""Levenberg-Marquardt on the Jacobian matrix: the solver of the global fitters, whose
problems have a handful of unknowns (roughness, Fresnel, a light offset...) and 10^4-10^6
residuals (every pixel of every frame).

optimistix's Levenberg-Marquardt works on the linearised residuals as a function
(`jax.linearize`) and evaluates it once per unknown for its QR, again for the transpose
and for the predicted reduction: each pass goes through the whole model. Here the
linearisation is the (M, P) Jacobian, the linearised residuals applied to the P unit
vectors (the same autodiff derivative, exactly), reduced at once to the P x P normal equations; a step is a Cholesky solve of
a P x P system (`benchmarks/fit_step.py` measures both solvers).

Why a solver of its own rather than the Jacobian matrix handed to optimistix (a
`jax.custom_jvp` whose tangent is `jacfwd(x) @ dx`): inside optimistix 0.1.0's
Levenberg-Marquardt that made the steps nondeterministic. The same start on the same data
(a near light at the lens, 160x128 x 6 frames) gave sigma 0.2499 in some processes and
1.4e-27 in others (an accepted step that raised the loss from 1.3e4 to 2.1e6), 5 fits of 8,
though the Jacobian computed outside the solver was bitwise the same; the cause inside the
loop was not found. Here a step is accepted only if it lowers the cost.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jax.scipy.linalg import cho_factor, cho_solve

from .._errors import CtjaxError
from .._status import Status
from .._typing import Array, Int

# Marquardt damping (relative to the diagonal of J^T J): its start and ceiling. Between
# steps it follows the gain ratio (Nielsen's rule, Madsen, Nielsen & Tingleff 2004, eq. 2.21).
_DAMPING = (1e-3, 1e12)


class DenseLM(eqx.Module):
    """Levenberg-Marquardt for few unknowns and many residuals, with the damped normal
    equations `(J^T J + lambda diag(J^T J)) dy = -J^T r` solved by Cholesky.

    A step is accepted only if it lowers the cost `|r|^2`: the cost never rises, whatever
    the rounding. lambda then follows the gain ratio rho, the cost's decrease over the one
    the linearised residuals predict (Nielsen's rule: x max(1/3, 1 - (2 rho - 1)^3) on
    accepting; x 2, 4, 8... on rejecting in a row, the Jacobian kept). Where Gauss-Newton
    overshoots along a curved valley (rho ~ 0.15 at every step, the iterates zig-zagging
    in), the damping grows instead of shrinking: a near light with inverse-square and spot
    falloff on the demo capture took 36-56 steps instead of 60-79 to the same cost. Each trial point is
    linearised (`jax.linearize`: its residuals, and the derivative's program that reuses
    them) and the Jacobian formed only where the point is kept; entries that are not finite count as
    0, and a trial whose cost is not finite is rejected, so no NaN reaches the solution.

    Stops `successful` when a step is within `atol + rtol * |y|` (max norms) and, if it was
    accepted, lowered the cost by at most `atol + rtol * cost` (optimistix's Cauchy test);
    `max_steps_reached` when `max_steps` iterations (accepted or not) ran first;
    `nonfinite` when the cost at `y0` is not finite. `y0` may be any pytree of arrays of one
    floating dtype, in which the solve runs. The number of steps counts every iteration.
    """

    rtol: float = eqx.field(static=True, default=1e-6)
    atol: float = eqx.field(static=True, default=1e-6)

    def __check_init__(self):
        for name in ("rtol", "atol"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not value >= 0:
                raise CtjaxError(f"{name} must be a nonnegative number, got {value!r}")

    def __call__(
        self, fn, y0, max_steps: int, *, has_aux: bool = False
    ) -> tuple[object, Int[Array, ""], Array] | tuple[object, Int[Array, ""], Array, object]:
        """Minimise `|fn(y)|^2` from `y0` (`fn(y) -> (M,)`, or `(M,), aux` with `has_aux`)
        in at most `max_steps` iterations. Returns the solution (shaped as `y0`), its
        `Status` code and the number of iterations (and `fn`'s aux at the solution)."""
        flat, unravel = ravel_pytree(y0)
        if not has_aux:
            plain = fn
            fn = lambda y: (plain(y), None)  # noqa: E731
        if flat.size == 0:
            done = jnp.asarray(Status.successful.value), jnp.asarray(0)
            return (y0, *done, fn(y0)[1]) if has_aux else (y0, *done)
        dtype = flat.dtype
        d0, ceiling = _DAMPING

        def residuals(x):
            r, aux = fn(unravel(x))
            return r.reshape(-1).astype(dtype), aux

        def normal_equations(tangents, r):
            jac = jax.vmap(tangents, out_axes=1)(jnp.eye(flat.size, dtype=dtype))
            jac = jnp.nan_to_num(jac, nan=0.0, posinf=0.0, neginf=0.0)
            return jac.T @ jac, jac.T @ r

        def tiny(y, dy):
            return jnp.max(jnp.abs(dy)) <= self.atol + self.rtol * jnp.max(jnp.abs(y))

        def step(carry):
            # The point `x` is evaluated (the start, then each trial y + dy) and linearised:
            # its cost and aux, and, only where it is kept (the start, or a lower cost), its
            # normal equations from the linearisation. The model appears once in the
            # compiled loop, and its derivative once (a Jacobian's forward pass beside a
            # trial's residuals would be two copies of the model: seconds to compile each).
            x, first, (dy, solved, predicted), y, cost, linear, aux, (damping, grow), n, _ = carry
            r, tangents, trial_aux = jax.linearize(residuals, x, has_aux=True)
            trial_cost = r @ r
            better = first | (solved & jnp.isfinite(trial_cost) & (trial_cost < cost))
            finite = ~first | jnp.isfinite(trial_cost)  # false only at a start not finite
            done = ~first & (
                solved
                & tiny(y, dy)
                & (~better | (cost - trial_cost <= self.atol + self.rtol * cost))
            )
            # Gain ratio: the cost's decrease over the linear model's (> 0 for any dy).
            gain = (cost - trial_cost) / jnp.maximum(predicted, jnp.finfo(dtype).tiny)
            accepted = damping * jnp.maximum(1 / 3, 1 - (2 * gain - 1) ** 3)
            damping, grow = (
                jnp.where(
                    first,
                    damping,
                    jnp.minimum(jnp.where(better, accepted, damping * grow), ceiling),
                ),
                jnp.where(first, grow, jnp.where(better, 2.0, grow * 2)).astype(dtype),
            )
            linear = jax.lax.cond(better, lambda: normal_equations(tangents, r), lambda: linear)
            y, cost, aux = jax.tree.map(
                lambda new, old: jnp.where(better, new, old),
                (x, trial_cost, trial_aux),
                (y, cost, aux),
            )
            # The next trial, from the normal equations at y.
            normal, gradient = linear
            diagonal = jnp.diag(normal)
            scale = jnp.maximum(diagonal, 1e-12 * jnp.max(diagonal)) + jnp.finfo(dtype).tiny
            factor = cho_factor(normal + jnp.diag(damping * scale))
            dy = -cho_solve(factor, gradient)
            solved = jnp.all(jnp.isfinite(dy))
            dy = jnp.where(solved, dy, 0)
            predicted = damping * (dy * scale) @ dy - gradient @ dy
            return (
                y + dy,
                jnp.asarray(False),
                (dy, solved, predicted),
                y,
                cost,
                linear,
                aux,
                (damping, grow),
                n + ~first,
                done | ~finite,
            )

        def running(carry):
            *_, iterations, done = carry
            return ~done & (iterations < max_steps)

        if max_steps <= 0:
            r, aux = fn(y0)
            finite = jnp.isfinite(jnp.sum(r.astype(dtype) ** 2))
            code = jnp.where(finite, Status.max_steps_reached.value, Status.nonfinite.value)
            return (y0, code, jnp.asarray(0), aux) if has_aux else (y0, code, jnp.asarray(0))
        zero = jnp.zeros(flat.size, dtype)
        no_aux = jax.tree.map(
            lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(lambda: fn(y0)[1])
        )
        start = (
            flat,
            jnp.asarray(True),
            (zero, jnp.asarray(True), jnp.asarray(0, dtype)),
            flat,
            jnp.asarray(jnp.inf, dtype),
            (jnp.zeros((flat.size, flat.size), dtype), zero),
            no_aux,
            (jnp.asarray(d0, dtype), jnp.asarray(2.0, dtype)),
            jnp.asarray(0),
            jnp.asarray(False),
        )
        carry = jax.lax.while_loop(running, step, start)
        y, cost, aux, iterations, done = carry[3], carry[4], carry[6], carry[8], carry[9]
        code = jnp.where(
            jnp.isfinite(cost),
            jnp.where(done, Status.successful.value, Status.max_steps_reached.value),
            Status.nonfinite.value,
        )
        return (unravel(y), code, iterations, aux) if has_aux else (unravel(y), code, iterations)
