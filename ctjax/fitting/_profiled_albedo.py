"""A point's Gaussian cost with its albedo profiled, for every set of lobe weights at once.

`facet_marginal` scores each tracked point's views at every facet node, for every lobe
weight F_tilde (G), subset of its frames (T) and noise scale (NS). The albedo fitted to
`values - g L` is linear in the weights g, so the sum of squares is a quadratic in g whose
coefficients are sums over the views (`view_sums`), computed once per node and subset;
each weight then costs a handful of products (`gaussian_ssr`) instead of a pass over the
views, and each noise scale one division (`gaussian_nll`). Exactly the residuals' own sum of
squares (to rounding), the albedo clipped at 0 included.
"""

import jax.numpy as jnp


def view_sums(diffuse, lobes, values, subset_weights) -> dict:
    """The weighted sums over one point's views that give its Gaussian cost for every set
    of lobe weights in closed form (`gaussian_ssr`), per facet (N) and subset of its views
    (T; weights `subset_weights` (T, M)): `diffuse` (M,) the diffuse lobe's column (the
    same about every facet), `lobes` (N, K', M) the other lobes' columns about each facet,
    `values` (C, M). The albedo's projection is taken out of the values and of the lobes'
    columns before their products are summed (`r0`, `perp`), not subtracted after: no
    cancellation in float32. Sums over the views are products of matrices over the facets
    (one each), not a batch of small ones per facet."""
    ws = jnp.maximum(subset_weights, 0.0)
    counted = ws > 0
    b = jnp.where(counted, diffuse, 0.0)  # (T, M)
    v = jnp.where(counted[:, None], values, 0.0)  # (T, C, M)
    lobes = jnp.where(jnp.any(counted, 0), lobes, 0.0)  # a view no subset counts: no NaN
    bb = jnp.maximum(jnp.sum(ws * b * b, -1), 1e-30)  # (T,)
    albedo = jnp.sum((ws * b)[:, None] * v, -1) / bb[:, None]  # (T, C): without the lobes
    beta = jnp.einsum("tm,nkm->ntk", ws * b, lobes) / bb[:, None]  # (N, T, K'): their share
    r0 = v - albedo[..., None] * b[:, None]  # (T, C, M)
    perp = lobes[:, None] - beta[..., None] * b[:, None]  # (N, T, K', M)
    return {
        "albedo": jnp.broadcast_to(albedo, (lobes.shape[0], *albedo.shape)),
        "beta": beta,
        "rr": jnp.sum(ws[:, None] * r0 * r0, -1),  # (T, C): the same for every facet
        "rL": jnp.einsum("tcm,nkm->ntck", ws[:, None] * r0, lobes),  # (N, T, C, K')
        "LL_perp": jnp.sum(ws[:, None, None] * perp[:, :, :, None] * perp[:, :, None], -1),
        "vv": jnp.sum(ws[:, None] * v * v, -1),  # (T, C)
        "vL": jnp.einsum("tcm,nkm->ntck", ws[:, None] * v, lobes),
        "LL": jnp.einsum("tm,nkm,njm->ntkj", ws, lobes, lobes),
        "count": values.shape[0] * jnp.sum(ws, -1),  # (T,)
    }


def gaussian_ssr(sums: dict, g):
    """The sum of squares (...) of the views whose `view_sums` are `sums` (leaves (...,
    C) etc.) under lobe weights `g` (K', C), the albedo refitted to `values - g L` (the
    projection's where that albedo is positive, the raw residual's where it is clipped at
    0): exactly the residuals' own."""
    albedo = sums["albedo"] - jnp.einsum("kc,...k->...c", g, sums["beta"])
    projected = (
        sums["rr"]
        - 2 * jnp.einsum("kc,...ck->...c", g, sums["rL"])
        + jnp.einsum("kc,jc,...kj->...c", g, g, sums["LL_perp"])
    )
    raw = (
        sums["vv"]
        - 2 * jnp.einsum("kc,...ck->...c", g, sums["vL"])
        + jnp.einsum("kc,jc,...kj->...c", g, g, sums["LL"])
    )
    return jnp.sum(jnp.maximum(jnp.where(albedo > 0, projected, raw), 0.0), -1)


def gaussian_nll(ssr, count, noise):
    """The Gaussian negative log-likelihood (..., NS) of `count` values (...) whose sum of
    squares is `ssr` (...), at each noise scale `noise` (NS,)."""
    return ssr[..., None] / (2 * noise * noise) + count[..., None] * jnp.log(noise)
