"""Residuals whose Jacobian is a matrix, computed once per linearisation.

optimistix's Levenberg-Marquardt linearises the residuals at every accepted step
(`jax.linearize`) and then evaluates that linear function once per parameter to build the
damped system, again for its transpose, and again for the predicted reduction: each pass
goes through the whole model. For the fitters' problems (10^4-10^5 residuals, a handful of
parameters) that made one step cost 18 ms at 8192 pixels where the model and its
forward-mode Jacobian cost 1.5 ms. Here the linearisation is the (M, P) Jacobian itself,
from `jax.jacfwd` (the same autodiff Jacobian, exactly): every later pass is a matrix
product. 3.8x faster per step at 8192 pixels (`benchmarks/fit_step.py`).

Not used by the fitters: inside optimistix 0.1.0's Levenberg-Marquardt it made the steps
nondeterministic. The same start on the same data (near light at the lens, 160x128 x 6
frames, one free roughness) gave sigma 0.2499 in some processes and 1.4e-27 in others (an
accepted step that raised the loss from 1.3e4 to 2.1e6), 5 of 8 fits, also with
single-threaded Eigen. The plain residuals, or `jax.jvp` inside the same custom rule, gave
0.2499 in 8 of 8. The Jacobian and its transpose computed outside the solver are bitwise
equal to autodiff's, so the fault is in how the solver's loop uses them; it is not found
yet (`sum(J * dx)` instead of `J @ dx` is as nondeterministic: not the matrix product; the
fitted sigma also varied in its 10th digit between processes).
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
