"""One entry point for every least-squares solver ctjax accepts."""

import jax
import optimistix as optx

from .._status import Status
from .._typing import Array, Int
from ._closed_form_lm import ClosedFormLM
from ._dense_lm import DenseLM

# What `solver=` accepts.
Solver = optx.AbstractLeastSquaresSolver | DenseLM | ClosedFormLM


def least_squares(fn, solver, y0, max_steps: int) -> tuple[object, Int[Array, ""], Array]:
    """Minimise `|fn(y)|^2` from `y0` with `solver`: any optimistix least-squares solver
    (`optx.LevenbergMarquardt`...), or a ctjax solver object (`DenseLM`, `ClosedFormLM`),
    in at most `max_steps` steps. Returns the solution, its `Status` code and the number of
    steps: callers take the solver as an argument and never ask which one it is."""
    # Jitted: the solvers call `fn` at several places (start, trial points, Jacobian), and
    # pjit's cache traces it once for all of them; XLA inlines the call.
    fn = jax.jit(fn)
    if isinstance(solver, optx.AbstractLeastSquaresSolver):
        solution = optx.least_squares(
            lambda y, _: fn(y), solver, y0, max_steps=max_steps, throw=False
        )
        status = Status.of_optimistix(solution.result)
        return solution.value, status, solution.stats["num_steps"]
    return solver(fn, y0, max_steps)
