"""The facet marginal's closed forms: a point's Gaussian cost for every lobe weight from sums
over its views (`ctjax.fitting._profiled_albedo`), and the sum over the facet nodes as a
product of matrices (`_over_the_nodes`), each against the direct computation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ctjax.fitting._facet_marginal import _over_the_nodes
from ctjax.fitting._profiled_albedo import gaussian_nll, gaussian_ssr, view_sums


def _direct_ssr(diffuse, lobe, values, ws, g):
    """The sum of squares with the albedo refitted to values - g L and clipped at 0."""
    counted = ws > 0
    b = np.where(counted, diffuse, 0.0)
    target = np.where(counted, values, 0.0) - g[:, None] * lobe[None]  # (C, M)
    albedo = np.sum(ws * b * target, -1) / max(np.sum(ws * b * b), 1e-30)
    r = target - np.maximum(albedo, 0.0)[:, None] * b
    return np.sum(np.where(counted, ws * r * r, 0.0))


@pytest.mark.parametrize("dtype, rtol", [(np.float64, 1e-9), (np.float32, 2e-3)])
def test_the_sums_give_every_weights_sum_of_squares(dtype, rtol):
    """Random views (one with weight 0 and a NaN value it must not read), the lobe at 5
    facets, 3 subsets; weights from none to one that drives a channel's albedo below 0
    (the clipped case)."""
    rng = np.random.default_rng(0)
    views = 9
    diffuse = rng.uniform(0.2, 1.0, views)
    lobes = rng.uniform(0.0, 2.0, (5, 1, views))
    values = rng.uniform(0.1, 0.8, (3, views))
    values[:, 4] = np.nan
    weights = rng.uniform(0.5, 1.0, views)
    weights[4] = 0.0
    subsets = np.stack([weights, np.where(np.arange(views) % 2 == 0, weights, 0.0), weights])
    subsets[2, :3] = 0.0
    sums = view_sums(*(jnp.asarray(a, dtype) for a in (diffuse, lobes, values, subsets)))
    for g in (np.zeros(3), np.array([0.01, 0.05, 0.2]), np.array([3.0, 0.1, 5.0])):
        ssr = np.asarray(gaussian_ssr(sums, jnp.asarray(g[None], dtype)))  # (N, T)
        assert ssr.dtype == dtype
        direct = [
            [_direct_ssr(diffuse, lobes[n, 0], values, ws, g) for ws in subsets] for n in range(5)
        ]
        np.testing.assert_allclose(ssr, direct, rtol=rtol)
    noise = jnp.asarray([0.01, 0.02], dtype)
    nll = gaussian_nll(jnp.asarray(ssr, dtype), sums["count"], noise)
    count = 3 * subsets.sum(-1)
    expected = ssr[..., None] / (2 * np.asarray(noise) ** 2) + count[:, None] * np.log(noise)
    np.testing.assert_allclose(nll, expected, rtol=rtol)


def test_the_sum_over_the_nodes_is_the_logsumexp_and_says_when_it_underflows():
    rng = np.random.default_rng(1)
    log_weights = rng.normal(-5.0, 3.0, (4, 30))  # (SM, N)
    costs = rng.uniform(0.0, 60.0, (30, 3, 2))  # (N, T, NS)
    best = costs.min(0)
    ll, underflow = _over_the_nodes(log_weights, jnp.exp(best - costs), best)
    joint = log_weights[None, :, None, :] - np.moveaxis(costs, 0, -1)[:, None]
    np.testing.assert_allclose(ll, jax.scipy.special.logsumexp(joint, -1), rtol=1e-12)
    assert not underflow
    # The likeliest node e^-800 below the prior's peak, the peak's node e^-900 below it in
    # likelihood: every product underflows, and the sum says so.
    log_weights, costs = np.array([[0.0, -800.0]]), np.array([900.0, 0.0])[:, None, None]
    _, underflow = _over_the_nodes(log_weights, jnp.exp(costs.min(0) - costs), costs.min(0))
    assert underflow


def test_every_point_takes_the_exact_sums_again_only_where_the_fast_ones_underflowed():
    """`every_point`: the fast outputs where they did not underflow, the exact ones where
    they did (every 7th of 45 points, across batches of 8 and the padded last one), the
    exact function run on as few batches as the underflowed points fill (6 in batches of
    4: twice)."""
    from ctjax.fitting._facet_marginal import every_point

    calls = []

    def fast(x):
        return x * 10.0, x[:, None] + 0.5, jnp.mod(x, 7) == 3

    def exact(x):
        jax.debug.callback(lambda: calls.append(1))
        return -x, -x[:, None]

    index = np.arange(45.0)
    out, second = every_point(fast, exact, jnp.asarray(index), at_once=8, exact_at_once=4)
    flagged = index % 7 == 3
    np.testing.assert_array_equal(out, np.where(flagged, -index, index * 10))
    np.testing.assert_array_equal(second[:, 0], np.where(flagged, -index, index + 0.5))
    assert len(calls) == 2
