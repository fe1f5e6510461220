"""Residuals whose Jacobian is a matrix, computed once per linearisation.

optimistix's Levenberg-Marquardt linearises the residuals at every accepted step
(`jax.linearize`) and then evaluates that linear function once per parameter to build the
damped system, again for its transpose, and again for the predicted reduction: each pass
goes through the whole model. For the fitters' problems (10^4-10^5 residuals, a handful of
parameters) that made one step cost 18 ms at 8192 pixels where the model and its
forward-mode Jacobian cost 1.5 ms. Here the linearisation is the (M, P) Jacobian itself,
from `jax.jacfwd` (the same autodiff Jacobian, exactly): every later pass is a matrix
product. 3.8x faster per step at 8192 pixels (`benchmarks/fit_step.py`).
"""

from collections.abc import Callable

import jax
from jax.flatten_util import ravel_pytree


def matrix_jacobian(residuals: Callable) -> Callable:
    """`residuals(y, args) -> (M,)` for `optimistix.least_squares`, with its forward-mode
    derivative a stored Jacobian matrix (see the module's docstring). `y` may be any pytree
    of arrays of one dtype. Only `y` is differentiated: anything else the residuals depend
    on is a constant of the solve (as it is to optimistix)."""

    def wrapped(y, args):
        flat, unravel = ravel_pytree(y)

        def evaluate(x):
            return residuals(unravel(x), args)

        @jax.custom_jvp
        def linearised_as_matrix(x):
            return evaluate(x)

        @linearised_as_matrix.defjvp
        def _jvp(primals, tangents):
            (x,), (dx,) = primals, tangents
            return evaluate(x), jax.jacfwd(evaluate)(x) @ dx

        return linearised_as_matrix(flat)

    return wrapped
