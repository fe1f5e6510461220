"""Levenberg-Marquardt on the Jacobian matrix: the solver of the global fitters, whose
problems have a handful of unknowns (roughness, Fresnel, a light offset...) and 10^4-10^6
residuals (every pixel of every frame).

optimistix's Levenberg-Marquardt works on the linearised residuals as a function
(`jax.linearize`) and evaluates it once per unknown for its QR, again for the transpose
and for the predicted reduction: each pass goes through the whole model. Here the
linearisation is the (M, P) Jacobian from `jax.jacfwd` (the same autodiff derivative,
exactly), reduced at once to the P x P normal equations; a step is a Cholesky solve of
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
    falloff on the demo capture took 36-56 steps instead of 60-79 to the same cost. The Jacobian is
    `jax.jacfwd`'s, recomputed at every accepted point; entries that are not finite count as
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

    def __call__(self, fn, y0, max_steps: int) -> tuple[object, Int[Array, ""], Array]:
        """Minimise `|fn(y)|^2` from `y0` (`fn(y) -> (M,)`) in at most `max_steps`
        iterations. Returns the solution (shaped as `y0`), its `Status` code and the
        number of iterations."""
        flat, unravel = ravel_pytree(y0)
        if flat.size == 0:
            return y0, jnp.asarray(Status.successful.value), jnp.asarray(0)
        dtype = flat.dtype
        d0, ceiling = _DAMPING

        # Jitted inside the trace: its three uses (the start, the trial points and the
        # Jacobian) share one trace of `fn` (pjit's cache) instead of tracing it three
        # times; XLA inlines the call, so the compiled program is the same.
        @jax.jit
        def residuals(x):
            return fn(unravel(x)).reshape(-1).astype(dtype)

        def normal_equations(x, _):
            jac, r = jax.jacfwd(lambda x: (residuals(x),) * 2, has_aux=True)(x)
            jac = jnp.nan_to_num(jac, nan=0.0, posinf=0.0, neginf=0.0)
            return jac.T @ jac, jac.T @ r, r @ r

        def tiny(y, dy):
            return jnp.max(jnp.abs(dy)) <= self.atol + self.rtol * jnp.max(jnp.abs(y))

        def step(carry):
            y, cost, linear, stale, (damping, grow), iterations, _ = carry
            # The normal equations at y, recomputed only after an accepted step (and at the
            # start, where they give the first cost too): one copy of the Jacobian's program
            # and one of the residuals' (the trials) in the compiled loop.
            normal, gradient, cost = jax.lax.cond(
                stale, normal_equations, lambda _, known: (*known, cost), y, linear
            )
            finite = jnp.isfinite(cost)  # false only at a start that is not finite
            diagonal = jnp.diag(normal)
            scale = jnp.maximum(diagonal, 1e-12 * jnp.max(diagonal)) + jnp.finfo(dtype).tiny
            factor = cho_factor(normal + jnp.diag(damping * scale))
            dy = -cho_solve(factor, gradient)
            solved = jnp.all(jnp.isfinite(dy))
            dy = jnp.where(solved, dy, 0)
            trial = y + dy
            r = residuals(trial)
            trial_cost = r @ r
            better = finite & solved & jnp.isfinite(trial_cost) & (trial_cost < cost)
            done = (
                solved
                & tiny(y, dy)
                & (~better | (cost - trial_cost <= self.atol + self.rtol * cost))
            )
            # Gain ratio: the cost's decrease over the linear model's (> 0 for any dy).
            predicted = damping * (dy * scale) @ dy - gradient @ dy
            gain = (cost - trial_cost) / jnp.maximum(predicted, jnp.finfo(dtype).tiny)
            accepted = damping * jnp.maximum(1 / 3, 1 - (2 * gain - 1) ** 3)
            return (
                jnp.where(better, trial, y),
                jnp.where(better, trial_cost, cost),
                (normal, gradient),
                better,
                (
                    jnp.minimum(jnp.where(better, accepted, damping * grow), ceiling),
                    jnp.where(better, 2.0, grow * 2).astype(dtype),
                ),
                iterations + finite,
                done | ~finite,
            )

        def running(carry):
            *_, iterations, done = carry
            return ~done & (iterations < max_steps)

        if max_steps <= 0:
            finite = jnp.isfinite(jnp.sum(residuals(flat) ** 2))
            code = jnp.where(finite, Status.max_steps_reached.value, Status.nonfinite.value)
            return y0, code, jnp.asarray(0)
        start = (
            flat,
            jnp.asarray(jnp.inf, dtype),  # the first step computes it
            (jnp.zeros((flat.size, flat.size), dtype), jnp.zeros(flat.size, dtype)),
            jnp.asarray(True),
            (jnp.asarray(d0, dtype), jnp.asarray(2.0, dtype)),
            jnp.asarray(0),
            jnp.asarray(False),
        )
        y, cost, _, _, _, iterations, done = jax.lax.while_loop(running, step, start)
        code = jnp.where(
            jnp.isfinite(cost),
            jnp.where(done, Status.successful.value, Status.max_steps_reached.value),
            Status.nonfinite.value,
        )
        return unravel(y), code, iterations
