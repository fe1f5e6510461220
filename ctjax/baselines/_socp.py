"""The paper's estimator, faithfully: problem (6) as an SOCP inside its branch-and-bound.

Malti & Bartoli solve, for a fixed sigma,

    min t  s.t.  || I - (a rho + b F sigma^-2 exp(-c / sigma^2)) ||_2 <= t,  rho, F >= 0     (6)

(with YALMIP; here cvxpy and the Clarabel solver), and search sigma by branch-and-bound:
(a) split the interval into sub-intervals; (b) test feasibility at each centre with the upper
bound t <= t_best of the best solution so far, dropping infeasible centres; (c) solve (6) at
the remaining centres; (d) keep the sub-interval with the least RGB error; repeat until the
interval is shorter than the threshold. rho and F are per colour channel, sigma shared.

Requires the optional dependencies `cvxpy` and `clarabel` (`pip install ctjax[baseline]`).
"""

import dataclasses
import time

import numpy as np

from .._errors import CtjaxError


@dataclasses.dataclass(frozen=True)
class SOCPResult:
    sigma: float
    rho_tilde: np.ndarray  # (3,)
    F_tilde: np.ndarray  # (3,)
    cost: float  # sum of squared residuals over the three channels (= t^2)
    solves: int
    feasibility_tests: int
    seconds: float


def _import_cvxpy():
    try:
        import cvxpy as cp
    except ImportError as error:
        raise CtjaxError(
            "the SOCP baseline needs cvxpy and clarabel: pip install 'ctjax[baseline]'"
        ) from error
    return cp


def socp_branch_and_bound(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    values: np.ndarray,
    *,
    lo: float = 1e-5,
    hi: float = 1.0,
    threshold: float = 1e-3,
    subintervals: int = 10,
) -> SOCPResult:
    """The paper's BnB over sigma with problem (6) solved by Clarabel at every centre.

    `a`, `b`, `c` (N,) are the per-pixel coefficients of eq. (4): a = N.L / pi,
    b = 1 / (pi (N.L)(N.V) cos^4 alpha), c = tan^2 alpha; `values` (N, 3) the RGB.
    """
    cp = _import_cvxpy()
    started = time.perf_counter()
    a, b, c = (np.asarray(x, np.float64) for x in (a, b, c))
    values = np.asarray(values, np.float64)
    n = len(a)
    specular_column = cp.Parameter(n)
    bound = cp.Parameter(nonneg=True)
    rho, fresnel, t = cp.Variable(3, nonneg=True), cp.Variable(3, nonneg=True), cp.Variable()
    residual = values - cp.outer(a, rho) - cp.outer(specular_column, fresnel)
    cone = cp.norm(cp.vec(residual, order="F"), 2) <= t
    problem = cp.Problem(cp.Minimize(t), [cone])
    feasibility = cp.Problem(cp.Minimize(0), [cone, t <= bound])

    def column(sigma):
        with np.errstate(under="ignore", over="ignore"):
            return b * np.exp(-c / sigma**2) / sigma**2

    best = (np.inf, None, None, None)  # t, sigma, rho, F
    solves = tests = 0
    low, high = lo, hi
    while True:
        width = (high - low) / subintervals
        centres = low + width * (np.arange(subintervals) + 0.5)
        level = []
        for sigma in centres:
            specular_column.value = column(sigma)
            if np.isfinite(best[0]):
                bound.value = best[0]
                feasibility.solve(solver=cp.CLARABEL)
                tests += 1
                if feasibility.status not in ("optimal", "optimal_inaccurate"):
                    continue  # cannot beat the best solution so far
            problem.solve(solver=cp.CLARABEL)
            solves += 1
            if problem.status in ("optimal", "optimal_inaccurate"):
                level.append((float(t.value), sigma, rho.value.copy(), fresnel.value.copy()))
        if level:
            level_best = min(level, key=lambda item: item[0])
            if level_best[0] < best[0]:
                best = level_best
        if best[1] is None:
            raise CtjaxError("the SOCP baseline found no feasible solution")
        low = max(lo, best[1] - width / 2)
        high = min(hi, best[1] + width / 2)
        if high - low <= threshold:
            break
    _, sigma, rho_value, fresnel_value = best
    # Report the cost from the residuals (the solver's t carries its tolerance).
    model = np.outer(a, rho_value) + np.outer(column(sigma), fresnel_value)
    cost = float(np.sum((values - model) ** 2))
    return SOCPResult(
        float(sigma), rho_value, fresnel_value, cost, solves, tests, time.perf_counter() - started
    )
