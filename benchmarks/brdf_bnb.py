"""BRDF estimation by branch-and-bound over sigma: the paper's SOCP vs closed forms.

    python benchmarks/brdf_bnb.py [--sizes 10000 100000] [--skip-socp-above N]

On the same synthetic ring data (the paper's eq. 4 with known rho_tilde, F_tilde, sigma and
1 level of noise; K pixels, RGB), in one run, with the paper's branch-and-bound (10
sub-intervals per level, [1e-5, 1] down to 1e-3) for every method:

- SOCP: problem (6) with cvxpy + Clarabel at each centre, with the feasibility test.
- scipy-nnls: `scipy.optimize.nnls` per channel at each centre (what a careful NumPy user
  would write).
- numpy-closed-form: the exact 2-variable NNLS, vectorised NumPy.
- jax-closed-form float64 / float32: ctjax's compiled closed form (after compilation;
  compile time reported separately), plus ctjax's default search (32-point grids, 4
  candidate intervals per level) for reference.

Prints a table and one JSON line per method and size.
"""

import argparse
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _results import emit  # noqa: E402
from scipy.optimize import nnls as scipy_nnls  # noqa: E402

import ctjax  # noqa: E402
from ctjax.estimation import (  # noqa: E402
    PAPER,
    ShadingSamples,
    design_columns,
    design_geometry,
    grid_search,
    nnls_columns,
)

TRUTH = {"rho_tilde": [2.4, 1.1, 0.85], "F_tilde": [0.3, 0.3, 0.3], "sigma": 0.2}
LO, HI, THRESHOLD, SUBINTERVALS = 1e-5, 1.0, 1e-3, 10


def ring_data(k: int, seed: int = 0):
    """K ring pixels: L = V, the angle between N and V spread as around a highlight."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(np.radians(8), np.radians(35), k)
    cos = np.cos(angle)
    a = cos / np.pi
    b = 1 / (np.pi * cos**2 * cos**4)
    c = (1 - cos**2) / cos**2
    s = TRUTH["sigma"]
    clean = np.outer(a, TRUTH["rho_tilde"]) + np.outer(
        b * np.exp(-c / s**2) / s**2, TRUTH["F_tilde"]
    )
    values = clean + rng.normal(0, 1 / 255, clean.shape)
    tilt = rng.uniform(0, 2 * np.pi, k)
    view = np.stack([np.sin(angle) * np.cos(tilt), np.sin(angle) * np.sin(tilt), cos], -1)
    return a, b, c, values, view


def paper_bnb(cost_at):
    """The paper's BnB over sigma: keep the best sub-interval, until shorter than 1e-3."""
    best_sigma, best = None, np.inf
    low, high = LO, HI
    while True:
        width = (high - low) / SUBINTERVALS
        for sigma in low + width * (np.arange(SUBINTERVALS) + 0.5):
            cost = cost_at(sigma)
            if cost < best:
                best_sigma, best = sigma, cost
        low, high = max(LO, best_sigma - width / 2), min(HI, best_sigma + width / 2)
        if high - low <= THRESHOLD:
            return best_sigma


def specular_column(b, c, sigma):
    with np.errstate(under="ignore", over="ignore"):
        return b * np.exp(-c / sigma**2) / sigma**2


def scipy_nnls_fit(a, b, c, values):
    def solve(sigma):
        design = np.stack([a, specular_column(b, c, sigma)], -1)
        xs = [scipy_nnls(design, values[:, ch])[0] for ch in range(3)]
        return np.array(xs).T, float(np.sum((values - design @ np.array(xs).T) ** 2))

    sigma = paper_bnb(lambda s: solve(s)[1])
    x, cost = solve(sigma)
    return sigma, x, cost


def numpy_closed_form(a, b, c, values):
    """Exact 2-variable NNLS per channel from the normal equations, vectorised over channels."""

    def solve(sigma):
        g = specular_column(b, c, sigma)
        aa, ag, gg = a @ a, a @ g, g @ g
        ay, gy = a @ values, g @ values  # (3,)
        det = aa * gg - ag * ag
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = (gg * ay - ag * gy) / det
            f = (aa * gy - ag * ay) / det
        interior = (det > 1e-12 * aa * max(gg, 1e-300)) & (rho >= 0) & (f >= 0)
        rho_only = np.maximum(ay / aa, 0)
        f_only = np.maximum(gy / gg, 0) if gg > 0 else np.zeros(3)
        x = np.zeros((2, 3))
        for ch in range(3):
            candidates = [np.array([rho_only[ch], 0.0]), np.array([0.0, f_only[ch]])]
            if interior[ch]:
                candidates.append(np.array([rho[ch], f[ch]]))
            design = np.stack([a, g], -1)
            costs = [np.sum((values[:, ch] - design @ cand) ** 2) for cand in candidates]
            x[:, ch] = candidates[int(np.argmin(costs))]
        design = np.stack([a, g], -1)
        return x, float(np.sum((values - design @ x) ** 2))

    sigma = paper_bnb(lambda s: solve(s)[1])
    x, cost = solve(sigma)
    return sigma, x, cost


def jax_fit(samples, grid, candidates, zoom):
    @jax.jit
    def run(samples):
        geometry = design_geometry(PAPER, samples)  # once for every sigma, as `fit_brdf`

        def cost(params):
            columns = design_columns(PAPER, params, samples, geometry)
            return nnls_columns(columns, samples.values)[1]

        search = grid_search(
            cost,
            LO,
            HI,
            tolerance=THRESHOLD,
            grid=grid,
            candidates=candidates,
            zoom=zoom,
            dtype=samples.values.dtype,
        )
        x, best = nnls_columns(design_columns(PAPER, search.params, samples), samples.values)
        return search.params[0], x, best

    return run


def timed(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return out, float(np.median(times))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument(
        "--skip-socp-above",
        type=int,
        default=10**9,
        help="skip the (slow) SOCP baseline above this many pixels",
    )
    args = parser.parse_args()
    ctjax.tune_malloc()
    rows = []
    for k in args.sizes:
        a, b, c, values, view = ring_data(k)
        results = {}
        if k <= args.skip_socp_above:
            from ctjax.baselines import socp_branch_and_bound

            start = time.perf_counter()
            socp = socp_branch_and_bound(
                a, b, c, values, lo=LO, hi=HI, threshold=THRESHOLD, subintervals=SUBINTERVALS
            )
            results["socp-clarabel"] = (
                time.perf_counter() - start,
                socp.sigma,
                np.stack([socp.rho_tilde, socp.F_tilde]),
                socp.cost,
                None,
            )
        repeats = 3 if k >= 100_000 else 5
        out, seconds = timed(
            lambda a=a, b=b, c=c, values=values: scipy_nnls_fit(a, b, c, values), 1
        )
        results["scipy-nnls"] = (seconds, out[0], out[1], out[2], None)
        out, seconds = timed(
            lambda a=a, b=b, c=c, values=values: numpy_closed_form(a, b, c, values), repeats
        )
        results["numpy-closed-form"] = (seconds, out[0], out[1], out[2], None)
        for dtype in (np.float64, np.float32):
            v = ctjax.Vec3.from_array(jnp.asarray(view, dtype))
            normal = ctjax.Vec3.from_array(jnp.tile(jnp.asarray([0.0, 0.0, 1.0], dtype), (k, 1)))
            samples = ShadingSamples(normal, v, v, jnp.ones(k, dtype), jnp.asarray(values, dtype))
            for label, config in (("paper-bnb", (10, 1, 1)), ("ctjax-default", (32, 4, 2))):
                run = jax_fit(samples, *config)
                start = time.perf_counter()
                jax.block_until_ready(run(samples))
                compile_s = time.perf_counter() - start
                out, seconds = timed(lambda run=run, samples=samples: run(samples), repeats * 4)
                name = f"jax-closed-form-{np.dtype(dtype).name}" + (
                    "" if label == "paper-bnb" else "-default-search"
                )
                results[name] = (
                    seconds,
                    float(out[0]),
                    np.asarray(out[1]),
                    float(out[2]),
                    compile_s,
                )
        reference = results.get("socp-clarabel")
        for name, (seconds, sigma, x, cost, compile_s) in results.items():
            row = {
                "benchmark": "brdf_bnb",
                "method": name,
                "pixels": k,
                "seconds_per_fit": seconds,
                "compile_seconds": compile_s,
                "sigma": float(sigma),
                "rho_tilde": np.asarray(x)[0].tolist(),
                "F_tilde": np.asarray(x)[1].tolist(),
                "cost": float(cost),
                "speedup_vs_socp": (reference[0] / seconds) if reference else None,
                "speedup_vs_scipy_nnls": results["scipy-nnls"][0] / seconds,
                "relative_cost_vs_socp": (float(cost) / reference[3] - 1) if reference else None,
            }
            rows.append(row)
            print(
                f"K={k:>7} {name:<42} {1e3 * seconds:10.2f} ms  sigma {sigma:.5f}  "
                f"cost {float(cost):.6g}  x SOCP {row['speedup_vs_socp'] or float('nan'):9.1f}  "
                f"x scipy {row['speedup_vs_scipy_nnls']:6.1f}"
                + (f"  (compile {compile_s:.2f} s)" if compile_s else "")
            )
    print(f"truth: {TRUTH}")
    for row in rows:
        emit(row)


if __name__ == "__main__":
    main()
