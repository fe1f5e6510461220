"""One entry point for every least-squares solver ctjax accepts."""

import jax
import optimistix as optx

from .._status import Status
from .._typing import Array, Int
from ._closed_form_lm import ClosedFormLM
from ._dense_lm import DenseLM

# What `solver=` accepts.
Solver = optx.AbstractLeastSquaresSolver | DenseLM | ClosedFormLM


def least_squares(
    fn, solver, y0, max_steps: int, *, has_aux: bool = False
) -> tuple[object, Int[Array, ""], Array] | tuple[object, Int[Array, ""], Array, object]:
    """Minimise `|fn(y)|^2` from `y0` with `solver`: any optimistix least-squares solver
    (`optx.LevenbergMarquardt`...), or a ctjax solver object (`DenseLM`, `ClosedFormLM`),
    in at most `max_steps` steps. Returns the solution, its `Status` code and the number of
    steps: callers take the solver as an argument and never ask which one it is. With
    `has_aux`, `fn(y)` returns `(residuals, aux)` and `aux` at the solution comes fourth."""
    # Jitted: the solvers call `fn` at several places (start, trial points, Jacobian), and
    # pjit's cache traces it once for all of them; XLA inlines the call.
    fn = jax.jit(fn)
    if isinstance(solver, DenseLM):
        return solver(fn, y0, max_steps, has_aux=has_aux)
    residuals = (lambda y: fn(y)[0]) if has_aux else fn
    if isinstance(solver, optx.AbstractLeastSquaresSolver):
        solution = optx.least_squares(
            lambda y, _: residuals(y), solver, y0, max_steps=max_steps, throw=False
        )
        value = solution.value
        status = Status.of_optimistix(solution.result)
        steps = solution.stats["num_steps"]
    else:
        value, status, steps = solver(residuals, y0, max_steps)
    return (value, status, steps, fn(value)[1]) if has_aux else (value, status, steps)
