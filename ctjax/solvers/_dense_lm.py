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

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jax.scipy.linalg import cho_factor, cho_solve

from .._errors import CtjaxError
from .._status import Status
from .._typing import Array, Int


class JacobianBlocks(tuple):
    """A start `y0` whose elements are blocks of unknowns: DenseLM takes each block's
    Jacobian columns in a forward pass of its own, the other blocks held as constants, so
    that what depends only on them is computed once instead of once per column (autodiff's
    zero tangents). For unknowns that reach the residuals by different paths: a frame's
    exposure does not enter the shading that the light's offset and sigma do. A plain
    tuple to every other solver (a pytree of its blocks).

    Measured on a near light with a gain per frame (12 frames, 16384 points, 590k
    residuals; sigma, a lens-plane offset and 11 exposures): DenseLM from moved exposures
    2.00 s with the Jacobian in one pass, 1.66 s in the two blocks, the same 3 steps
    (`benchmarks/projection_sums.py`)."""


jax.tree_util.register_pytree_node(
    JacobianBlocks, lambda b: (tuple(b), None), lambda _, children: JacobianBlocks(children)
)


# Marquardt damping (relative to the diagonal of J^T J): its start and ceiling. Between
# steps it follows the gain ratio (Nielsen's rule, Madsen, Nielsen & Tingleff 2004, eq. 2.21).
_DAMPING = (1e-3, 1e12)
# The damping from which a passed stopping test is checked by a probe at the start's (see
# `DenseLM`): a step a tenth of Gauss-Newton's or shorter along the stiff directions. On a
# real sinus capture the near light's fits stopped at 0.15-2.3 after converging (a probe
# there never lowered the cost) and at 400-270000 where stalled (probes that lowered it
# by 0.3-0.7% came at 5800 and 40000).
_PROBE_FROM = 10.0


class DenseLM(eqx.Module):
    """Levenberg-Marquardt for few unknowns and many residuals, with the damped normal
    equations `(J^T J + lambda diag(J^T J)) dy = -J^T r` solved by Cholesky.

    A step is accepted only if it lowers the cost `|r|^2`: the cost never rises, whatever
    the rounding. lambda then follows the gain ratio rho, the cost's decrease over the one
    the linearised residuals predict (Nielsen's rule: x max(1/3, 1 - (2 rho - 1)^3) on
    accepting; x 2, 4, 8... on rejecting in a row, the Jacobian kept). Where Gauss-Newton
    overshoots along a curved valley (rho ~ 0.15 at every step, the iterates zig-zagging
    in), the damping grows instead of shrinking: a near light with inverse-square and spot
    falloff on the demo capture took 36-56 steps instead of 60-79 to the same cost. The
    Jacobian is autodiff's (forward mode), computed at the start and at every accepted
    point; entries that are not finite count as 0, and a trial whose cost is not finite is
    rejected, so no NaN reaches the solution.

    Stops `successful` when a step is within `atol + rtol * |y|` (max norms) and, if it was
    accepted, lowered the cost by at most `atol + rtol * cost` (optimistix's Cauchy test),
    unless the damping is heavy (from `_PROBE_FROM`: steps shrunk by rejections, or by a
    curved valley's small gain ratios): then the step at the starting damping is tried
    once more (a probe), and the solve goes on from it where it lowers the cost by more
    than that tolerance, else stops. A kink of the cost (a point's albedo clamped at 0 in
    the projection) stalls a heavily damped step, not always a Gauss-Newton one: a near
    light's offset on a real sinus capture stopped `successful` 1.9% above the cost the
    probes reach, with sigma 0.18 instead of 0.38;
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
        """Minimise `|fn(y)|^2` from `y0` (`fn(y) -> (M,)`, or `((M,), aux)` with
        `has_aux`) in at most `max_steps` iterations. Returns the solution (shaped as
        `y0`), its `Status` code and the number of iterations; with `has_aux`, `fn`'s aux at
        the solution fourth (kept by the loop: the model is not evaluated after it)."""
        flat, unravel = ravel_pytree(y0)
        if not has_aux:
            plain = fn
            fn = lambda y: (plain(y), None)  # noqa: E731
        if flat.size == 0:
            done = jnp.asarray(Status.successful.value), jnp.asarray(0)
            return (y0, *done, fn(y0)[1]) if has_aux else (y0, *done)
        dtype = flat.dtype

        # `fn` jitted (`least_squares` does): its uses (the start, the trials, the Jacobian)
        # then share one trace of it (pjit's cache); XLA inlines the call.
        def of_tree(y):
            r, aux = fn(y)
            return r.reshape(-1).astype(dtype), aux

        def residuals(x):
            return of_tree(unravel(x))

        spans = _blocks(y0)
        jacobian = (
            None if spans is None else functools.partial(_block_jacobian, of_tree, unravel, spans)
        )

        if max_steps <= 0:
            r, aux = residuals(flat)
            finite = jnp.isfinite(jnp.sum(r * r))
            code = jnp.where(finite, Status.max_steps_reached.value, Status.nonfinite.value)
            return (y0, code, jnp.asarray(0), aux) if has_aux else (y0, code, jnp.asarray(0))
        y, cost, aux, iterations, done = _loop(self, residuals, flat, max_steps, jacobian)
        code = jnp.where(
            jnp.isfinite(cost),
            jnp.where(done, Status.successful.value, Status.max_steps_reached.value),
            Status.nonfinite.value,
        )
        y = unravel(y)
        return (y, code, iterations, aux) if has_aux else (y, code, iterations)


def _blocks(y0) -> list[tuple[int, int]] | None:
    """For a `JacobianBlocks` start with unknowns in two blocks or more: each block's
    `(start, size)` in the flat unknowns; else None (one forward pass for all)."""
    if not isinstance(y0, JacobianBlocks):
        return None
    sizes = [int(ravel_pytree(block)[0].size) for block in y0]
    if sum(size > 0 for size in sizes) < 2:
        return None
    return [(sum(sizes[:i]), size) for i, size in enumerate(sizes)]


def _block_jacobian(of_tree, unravel, spans, x):
    """`jax.jacfwd` of `of_tree(unravel(x))` (residuals, aux), block by block
    (`JacobianBlocks`): each block's columns with the other blocks' unknowns passed as
    constants (not as zero tangents through the flat vector). Returns the Jacobian (M, N)
    and (residuals, aux)."""
    primal = unravel(x)
    columns, out = [], None
    for index, (start, size) in enumerate(spans):
        if size == 0:
            continue
        unravel_block = ravel_pytree(primal[index])[1]

        def of_block(z, index=index, unravel_block=unravel_block):
            tree = JacobianBlocks(
                unravel_block(z) if i == index else block for i, block in enumerate(primal)
            )
            r, aux = of_tree(tree)
            return r, (r, aux)

        jac, out = jax.jacfwd(of_block, has_aux=True)(x[start : start + size])
        columns.append(jac)
    return jnp.concatenate(columns, axis=1), out


def _normal_equations(jac, r):
    jac = jnp.nan_to_num(jac, nan=0.0, posinf=0.0, neginf=0.0)
    return jac.T @ jac, jac.T @ r


def _trial_step(linear, damping):
    """The damped Gauss-Newton step from the normal equations `linear` at y: `(dy,
    solved, predicted decrease, scale)` (dy is 0 where the solve is not finite)."""
    normal, gradient = linear
    dtype = normal.dtype
    diagonal = jnp.diag(normal)
    scale = jnp.maximum(diagonal, 1e-12 * jnp.max(diagonal)) + jnp.finfo(dtype).tiny
    dy = -cho_solve(cho_factor(normal + jnp.diag(damping * scale)), gradient)
    solved = jnp.all(jnp.isfinite(dy))
    dy = jnp.where(solved, dy, 0)
    return dy, solved, damping * (dy * scale) @ dy - gradient @ dy


def _judged(solver, y, dy, solved, predicted, cost, trial_cost, damping, grow, probing):
    """Whether the trial y + dy is kept (`better`), whether the solve is done, the damping
    after it (Nielsen's rule, see `DenseLM`) and whether the next trial is a probe: where
    the stopping test passes at a heavy damping (`_PROBE_FROM`), the step at the start's
    damping is tried before stopping; a probe (`probing`) ends the solve unless it lowers
    the cost by more than the test's tolerance."""
    dtype = y.dtype
    better = solved & jnp.isfinite(trial_cost) & (trial_cost < cost)
    # |y| over the finite unknowns: one at its domain's end (a knee's slope of 1 in a
    # channel it does not compress, 1 - 1e-9 in float64 but 1 in float32) is infinite
    # unconstrained, and would pass every step as small.
    size = jnp.max(jnp.where(jnp.isfinite(y), jnp.abs(y), 0))
    small = jnp.max(jnp.abs(dy)) <= solver.atol + solver.rtol * size
    slight = cost - trial_cost <= solver.atol + solver.rtol * cost
    passed = solved & small & (~better | slight)
    damped = damping >= _PROBE_FROM
    done = jnp.where(probing, ~better | slight, passed & ~damped)
    probe = ~probing & passed & damped
    # Gain ratio: the cost's decrease over the linear model's (> 0 for any dy).
    gain = (cost - trial_cost) / jnp.maximum(predicted, jnp.finfo(dtype).tiny)
    accepted = damping * jnp.maximum(1 / 3, 1 - (2 * gain - 1) ** 3)
    damping = jnp.minimum(jnp.where(better, accepted, damping * grow), _DAMPING[1])
    grow = jnp.where(better, 2.0, grow * 2)
    damping = jnp.where(probe, _DAMPING[0], damping).astype(dtype)
    return better, done, (damping, jnp.where(probe, 2.0, grow).astype(dtype)), probe


def _kept(better, new, old):
    return jax.tree.map(lambda a, b: jnp.where(better, a, b), new, old)


def _start_aux(residuals, flat):
    shapes = jax.eval_shape(lambda: residuals(flat)[1])
    return jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)


def _loop(solver, residuals, flat, max_steps, jacobian=None):
    """The Jacobian's forward pass (`jax.jacfwd`; `jacobian(x)` -> (J, (r, aux)) where
    given: `_block_jacobian`) at the start and at every kept point, in a `lax.cond` (one
    copy of its program), the trials' residuals beside it (one copy of the model's), and the
    aux of the point kept: nothing is evaluated after the loop."""
    dtype = flat.dtype

    def with_aux(x):
        r, aux = residuals(x)
        return r, (r, aux)

    def normal_equations(x, _):
        if jacobian is None:
            jac, (r, aux) = jax.jacfwd(with_aux, has_aux=True)(x)
        else:
            jac, (r, aux) = jacobian(x)
        return _normal_equations(jac, r), r @ r, aux

    def step(carry):
        y, cost, linear, aux, stale, (damping, grow), probing, iterations, _ = carry
        # The normal equations at y, recomputed only after an accepted step (and at the
        # start, where they give the first cost and aux too).
        linear, cost, aux = jax.lax.cond(
            stale, normal_equations, lambda _, known: known, y, (linear, cost, aux)
        )
        finite = jnp.isfinite(cost)  # false only at a start that is not finite
        dy, solved, predicted = _trial_step(linear, damping)
        r, trial_aux = residuals(y + dy)
        better, done, damping, probing = _judged(
            solver, y, dy, solved & finite, predicted, cost, r @ r, damping, grow, probing
        )
        y, cost, aux = _kept(better, (y + dy, r @ r, trial_aux), (y, cost, aux))
        done = done | ~finite
        return y, cost, linear, aux, better, damping, probing, iterations + finite, done

    start = (
        flat,
        jnp.asarray(jnp.inf, dtype),  # the first step computes it
        (jnp.zeros((flat.size, flat.size), dtype), jnp.zeros(flat.size, dtype)),
        _start_aux(residuals, flat),
        jnp.asarray(True),
        (jnp.asarray(_DAMPING[0], dtype), jnp.asarray(2.0, dtype)),
        jnp.asarray(False),
        jnp.asarray(0),
        jnp.asarray(False),
    )
    y, cost, _, aux, _, _, _, iterations, done = jax.lax.while_loop(
        lambda c: ~c[-1] & (c[-2] < max_steps), step, start
    )
    return y, cost, aux, iterations, done
