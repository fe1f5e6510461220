"""The least-squares solver objects (`ctjax.solvers`) on problems with known answers."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from ctjax import CtjaxError, Status
from ctjax.solvers import DenseLM, JacobianBlocks, least_squares

# A decay a * exp(-b t) + c sampled at 200 times, with a little deterministic noise.
_TIMES = jnp.linspace(0.0, 4.0, 200)
_TRUTH = (2.5, 1.3, 0.4)
_NOISE = 1e-3 * jnp.sin(37.0 * _TIMES)


def _decay(y):
    (a, b), c = y
    return a * jnp.exp(-b * _TIMES) + c


def _residuals(y):
    a, b, c = _TRUTH
    return _decay(y) - (a * jnp.exp(-b * _TIMES) + c + _NOISE)


def _start(dtype):
    return (jnp.asarray([1.0, 0.5], dtype), jnp.asarray(0.0, dtype))


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_dense_lm_reaches_the_minimum_optimistix_reaches(dtype):
    solver = DenseLM()
    solve = jax.jit(lambda y0: least_squares(_residuals, solver, y0, 100))
    y, status, steps = solve(_start(dtype))
    reference = optx.least_squares(
        lambda y, _: _residuals(y),
        optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8),
        _start(jnp.float64),
        max_steps=200,
    ).value
    assert Status(int(status)) is Status.successful and 0 < int(steps) < 100
    assert y[0].dtype == dtype and y[0].shape == (2,) and y[1].shape == ()
    tolerance = 1e-8 if dtype == jnp.float64 else 1e-3
    np.testing.assert_allclose(y[0], reference[0], rtol=tolerance)
    np.testing.assert_allclose(y[1], reference[1], rtol=tolerance, atol=tolerance)
    # The noise is small: the fit is near the truth too.
    np.testing.assert_allclose(jnp.append(y[0], y[1]), _TRUTH, rtol=2e-3)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_an_unknown_at_its_domains_end_does_not_stop_the_solve(dtype):
    """An unconstrained unknown that is infinite (a parameter at its domain's end: a knee's
    slope of 1 is 1 - 1e-9 in float64 and 1 in float32) counts in no step's size: the
    other unknowns reach the same minimum as without it. (It passed every step as small,
    so the solve stopped at its first rejected trial: the near light's map fits in float32
    after 1-3 steps on a real capture.)"""
    solver = DenseLM()
    plain, _, _ = least_squares(_residuals, solver, _start(dtype), 100)
    at_end = (_start(dtype), jnp.asarray(jnp.inf, dtype))
    y, status, steps = least_squares(lambda y: _residuals(y[0]), solver, at_end, 100)
    assert Status(int(status)) is Status.successful and int(steps) > 3
    assert float(y[1]) == np.inf
    np.testing.assert_allclose(y[0][0], plain[0], rtol=1e-6)
    np.testing.assert_allclose(y[0][1], plain[1], rtol=1e-6, atol=1e-6)


def test_dense_lm_never_raises_the_cost_and_reports_what_stopped_it():
    solver = DenseLM()
    cost = lambda y: float(jnp.sum(_residuals(y) ** 2))  # noqa: E731
    start = _start(jnp.float64)
    for steps in (1, 2, 3, 5):
        y, status, taken = least_squares(_residuals, solver, start, steps)
        assert cost(y) <= cost(start) and int(taken) == steps
        assert Status(int(status)) is Status.max_steps_reached
    # Started at its solution, it stops at once without moving.
    y, _, _ = least_squares(_residuals, solver, start, 100)
    again, status, taken = least_squares(_residuals, solver, y, 100)
    assert Status(int(status)) is Status.successful and int(taken) <= 3
    np.testing.assert_allclose(again[0], y[0], rtol=1e-9)


def test_dense_lm_keeps_nan_out_of_the_solution():
    solver = DenseLM()
    nan_start = (jnp.asarray([jnp.nan, 0.5]), jnp.asarray(0.0))
    y, status, _ = least_squares(_residuals, solver, nan_start, 50)
    assert Status(int(status)) is Status.nonfinite

    # Residuals that are NaN beyond b = 3: the solver never steps there.
    def guarded(y):
        return jnp.where(y[0][1] > 3.0, jnp.nan, _residuals(y))

    y, status, _ = least_squares(guarded, solver, _start(jnp.float64), 100)
    assert np.all(np.isfinite(y[0])) and Status(int(status)) is Status.successful
    np.testing.assert_allclose(y[0], _TRUTH[:2], rtol=2e-3)


def test_dense_lm_damps_where_gauss_newton_overshoots():
    """Freudenstein and Roth's problem from (0.5, -2) ends in its large-residual local
    minimum, where the Gauss-Newton step overshoots: the gain-ratio damping gets there in 19
    steps (29 when lambda shrank by 3 at every accepted step)."""

    def residuals(y):
        a, b = y
        return jnp.stack([a - 13 + ((5 - b) * b - 2) * b, a - 29 + ((b + 1) * b - 14) * b])

    solver = DenseLM()
    y, status, steps = least_squares(residuals, solver, jnp.asarray([0.5, -2.0]), 100)
    assert Status(int(status)) is Status.successful and int(steps) <= 22
    np.testing.assert_allclose(y, [11.41277900, -0.89680525], rtol=1e-6)
    np.testing.assert_allclose(jnp.sum(residuals(y) ** 2), 48.98425368, rtol=1e-9)


def test_dense_lm_probes_before_it_stops_under_heavy_damping():
    """The stopping test passed under a heavy damping (rejected trials, or a curved
    valley's small gain ratios shrinking the steps) is not trusted at once: the next trial
    is the step at the starting damping (a probe), and the solve goes on where it lowers
    the cost by more than the tolerance. On a real sinus capture a near light's offset
    stopped `successful` 1.9% above the cost a Gauss-Newton step reached from there."""
    from ctjax.solvers._dense_lm import _DAMPING, _judged

    solver = DenseLM()
    one = lambda x: jnp.asarray([x], jnp.float64)  # noqa: E731
    y, tiny = one(1.0), one(1e-9)

    def judged(damping, trial_cost, probing, dy=tiny):
        better, done, (new_damping, grow), probe = _judged(
            solver, y, dy, jnp.asarray(True), jnp.asarray(1e-3), jnp.asarray(1.0),
            jnp.asarray(trial_cost), jnp.asarray(damping), jnp.asarray(8.0), jnp.asarray(probing),
        )  # fmt: skip
        return bool(better), bool(done), float(new_damping), float(grow), bool(probe)

    # A tiny rejected step: under a light damping the solve is done; under a heavy one
    # (`_PROBE_FROM` on), the next trial is a probe at the starting damping.
    assert judged(_DAMPING[0], 1.0 + 1e-12, False) == (False, True, 8 * _DAMPING[0], 16.0, False)
    assert judged(1.0, 1.0 + 1e-12, False) == (False, True, 8.0, 16.0, False)
    assert judged(1e3, 1.0 + 1e-12, False) == (False, False, _DAMPING[0], 2.0, True)
    # A tiny accepted step, heavily damped: a probe too (the point is kept).
    better, done, damping, _, probe = judged(1e3, 1.0 - 1e-9, False)
    assert better and not done and probe and damping == _DAMPING[0]
    # The probe: rejected, or lowering the cost by no more than the tolerance, ends the solve;
    # lowering it by more goes on (with the damping by the gain ratio, no probe pending).
    assert judged(_DAMPING[0], 1.0 + 1e-6, True)[1]
    assert judged(_DAMPING[0], 1.0 - 1e-9, True)[:2] == (True, True)
    better, done, _, _, probe = judged(_DAMPING[0], 0.98, True, dy=one(0.3))
    assert better and not done and not probe


def test_dense_lm_settings_are_checked():
    with pytest.raises(CtjaxError, match="rtol must be a nonnegative number, got -1"):
        DenseLM(rtol=-1)
    with pytest.raises(CtjaxError, match="atol must be a nonnegative number, got 'x'"):
        DenseLM(atol="x")


def test_jacobian_blocks_give_the_same_solve():
    """A `JacobianBlocks` start: each block's columns in a pass of its own (the map fitter's
    shading and image effects), the same steps to the same solution as one pass, and the
    same to any other solver (a tuple of its blocks)."""

    def with_aux(y):
        r = _residuals(y)
        return r, jnp.sum(r * r)

    start = _start(jnp.float64)
    solve = jax.jit(lambda y0: least_squares(with_aux, DenseLM(), y0, 100, has_aux=True))
    y, status, steps, aux = solve(start)
    blocked = solve(JacobianBlocks(start))
    assert isinstance(blocked[0], JacobianBlocks) and len(blocked[0]) == 2
    assert int(blocked[1]) == int(status) and int(blocked[2]) == int(steps) > 0
    np.testing.assert_allclose(blocked[0][0], y[0], rtol=1e-12)
    np.testing.assert_allclose(blocked[0][1], y[1], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(blocked[3], aux, rtol=1e-12)
    # One block with unknowns: one pass, as without blocks; optimistix takes the tuple.
    lone = JacobianBlocks((start[0], ()))
    y_lone = jax.jit(
        lambda y0: least_squares(lambda b: _residuals((b[0], start[1])), DenseLM(), y0, 100)
    )(lone)[0]
    assert y_lone[1] == ()
    other = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)
    y_other = jax.jit(lambda y0: least_squares(_residuals, other, y0, 200))(JacobianBlocks(start))[
        0
    ]
    np.testing.assert_allclose(y_other[0], y[0], rtol=1e-6)


def test_the_aux_at_the_solution_comes_from_the_loop():
    """`has_aux`: `fn`'s aux at the solution (here the residuals' sum of squares, which is
    the solution's own), kept by DenseLM's loop and computed after optimistix's solve."""

    def with_aux(y):
        r = _residuals(y)
        return r, jnp.sum(r * r)

    start = _start(jnp.float64)
    for solver in (DenseLM(), optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)):
        y, status, steps, aux = jax.jit(
            lambda y0, s=solver: least_squares(with_aux, s, y0, 200, has_aux=True)
        )(start)
        assert Status(int(status)) is Status.successful and int(steps) > 0
        np.testing.assert_allclose(aux, jnp.sum(_residuals(y) ** 2), rtol=1e-12)
    # Without steps: the start's aux.
    y, status, steps, aux = least_squares(with_aux, DenseLM(), start, 0, has_aux=True)
    assert int(steps) == 0 and Status(int(status)) is Status.max_steps_reached
    np.testing.assert_allclose(aux, jnp.sum(_residuals(start) ** 2), rtol=1e-12)


@pytest.mark.parametrize(
    "solver",
    [DenseLM(), optx.LevenbergMarquardt(rtol=1e-6, atol=1e-6)],
    ids=["dense", "optimistix"],
)
def test_the_residual_function_is_traced_once_per_solve(solver):
    """`least_squares` jits the residual function, so that the solver's uses of it (start,
    trial points, Jacobian) share one trace: tracing the model is most of a fitter's
    compilation time."""
    traces = []

    def counted(y):
        traces.append(1)
        return _residuals(y)

    y, status, _ = jax.jit(lambda y0: least_squares(counted, solver, y0, 100))(_start(jnp.float64))
    assert len(traces) == 1 and Status(int(status)) is Status.successful
    np.testing.assert_allclose(jnp.append(y[0], y[1]), _TRUTH, rtol=2e-3)


def test_the_closed_form_solver_traces_the_residual_function_once():
    """The same for `ClosedFormLM` (2 unknowns), which calls it three times a step."""
    from ctjax.solvers import ClosedFormLM

    traces = []

    def counted(ab):
        traces.append(1)
        return _residuals((ab, jnp.asarray(_TRUTH[2])))

    solve = jax.jit(lambda y0: least_squares(counted, ClosedFormLM(iterations=30), y0, 30))
    y, _, _ = solve(jnp.asarray([1.0, 0.5]))
    assert len(traces) == 1
    np.testing.assert_allclose(y, _TRUTH[:2], rtol=2e-3)


def test_the_information_matrix_from_the_columns_is_jtj():
    """`gram` (the standard errors' J^T J, built from the Jacobian's columns taken apart
    for speed) is the same matrix as `jac.T @ jac`, in a jitted program as the covariance
    programs use it, for a Jacobian from `jax.jacfwd`."""
    from ctjax.solvers._gram import gram

    y = jnp.asarray([2.0, 1.1, 0.3])
    jacobian = jax.jacfwd(lambda y: _residuals(((y[0], y[1]), y[2])))(y)  # (200, 3)
    both = jax.jit(lambda j: (gram(j), j.T @ j))(jacobian)
    np.testing.assert_allclose(both[0], both[1], rtol=1e-12, atol=0)
    assert both[0].shape == (3, 3) and np.allclose(both[0], both[0].T)
