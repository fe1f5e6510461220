"""Levenberg-Marquardt for two unknowns, written out: a solver object for the per-pixel
problems that are solved by the hundred thousand under `vmap`."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._errors import CtjaxError
from .._status import Status
from .._typing import Array, Float, Int

# Marquardt damping (relative to the diagonal of J^T J): start, factors on accepting and on
# rejecting a step, and a ceiling (no overflow in float32 when every trial is rejected).
_DAMPING = (1e-3, 1 / 3, 4.0, 1e10)


class ClosedFormLM(eqx.Module):
    """Levenberg-Marquardt for 2 unknowns with the damped normal equations solved by the
    explicit 2x2 inverse, for exactly `iterations` iterations.

    No loop condition: under `vmap` the slowest problem sets the time anyway, and a fixed
    count compiles to a plain loop. Per iteration: the residuals and their Jacobian
    (`jax.jacfwd`, 2 columns), the step `(J^T J + lambda diag(J^T J)) dy = -J^T r`, accepted
    if it lowers the cost (then lambda / 3), else rejected (lambda x 4). A trial whose cost
    is not finite is rejected and Jacobian entries that are not finite count as 0, so no NaN
    reaches the solution.

    Status: `successful` where the last iteration's undamped Gauss-Newton step is within
    `atol + rtol * |y|` (max norms, optimistix's Cauchy test on y) or would lower the cost
    by at most `rtol` of it (a valley flat to rounding, e.g. in float32);
    `max_steps_reached` where neither holds; `nonfinite` where the cost at the solution is
    not finite (the solution is then `y0`). Steps count the accepted steps. Works in the
    dtype of `y0`.
    """

    iterations: int = eqx.field(static=True, default=10)
    rtol: float = eqx.field(static=True, default=1e-4)
    atol: float = eqx.field(static=True, default=1e-6)

    def __check_init__(self):
        if (
            not isinstance(self.iterations, int)
            or isinstance(self.iterations, bool)
            or self.iterations < 1
        ):
            raise CtjaxError(f"iterations must be a positive integer, got {self.iterations!r}")

    def __call__(
        self, fn, y0: Float[Array, "2"], max_steps: int | None = None
    ) -> tuple[Array, Int[Array, ""], Array]:
        """Minimise `|fn(y)|^2` from `y0`; `max_steps` is ignored (the solver runs exactly
        `iterations`). Returns the solution, its `Status` code and the accepted steps."""
        d0, shrink, grow, ceiling = _DAMPING
        dtype = y0.dtype

        def cost(y):
            r = fn(y)
            return r @ r

        def step(_, carry):
            y, damping, accepted, _, _ = carry
            # The residuals from the Jacobian's pass: one copy of `fn`'s program for both
            # (and one for the trial), which halves the loop's compile time.
            jac, r = jax.jacfwd(lambda y: (fn(y),) * 2, has_aux=True)(y)
            jac = jnp.nan_to_num(jac, nan=0.0, posinf=0.0, neginf=0.0)
            a, b, d = jac[:, 0] @ jac[:, 0], jac[:, 0] @ jac[:, 1], jac[:, 1] @ jac[:, 1]
            g0, g1 = jac[:, 0] @ r, jac[:, 1] @ r

            def solve(a, d):
                det = a * d - b * b
                safe = jnp.where(det > 0, det, 1)
                dy = -jnp.stack([d * g0 - b * g1, a * g1 - b * g0]) / safe
                ok = (det > 0) & jnp.all(jnp.isfinite(dy))
                return jnp.where(ok, dy, 0), ok

            # The damped step (the trial), and the Gauss-Newton one for the convergence test
            # (the damped one where J^T J is singular, e.g. without a prior).
            dy, _ = solve(a * (1 + damping), d * (1 + damping))
            newton, regular = solve(a, d)
            newton = jnp.where(regular, newton, dy)
            trial = cost(y + dy)
            better = jnp.isfinite(trial) & (trial < r @ r)
            y = jnp.where(better, y + dy, y)
            damping = jnp.minimum(jnp.where(better, damping * shrink, damping * grow), ceiling)
            # Converged: the Gauss-Newton step is small, or would hardly lower the cost (its
            # model's decrease is -g . newton), e.g. along a valley flat to rounding.
            small = (jnp.max(jnp.abs(newton)) <= self.atol + self.rtol * jnp.max(jnp.abs(y))) | (
                -(g0 * newton[0] + g1 * newton[1]) <= self.rtol * (r @ r)
            )
            return y, damping, accepted + better, small, jnp.where(better, trial, r @ r)

        start = (
            y0,
            jnp.asarray(d0, dtype),
            jnp.asarray(0),
            jnp.asarray(False),
            jnp.zeros((), dtype),
        )
        y, _, accepted, small, last = jax.lax.fori_loop(0, self.iterations, step, start)
        finite = jnp.isfinite(last) & jnp.all(jnp.isfinite(y))  # (last: the cost at y)
        code = jnp.where(
            finite,
            jnp.where(small, Status.successful.value, Status.max_steps_reached.value),
            Status.nonfinite.value,
        )
        return jnp.where(finite, y, y0), code, accepted
