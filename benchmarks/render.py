"""Render throughput of the jitted ctjax renderer against vectorised NumPy, and the roofline.

    python benchmarks/render.py [--width 1920 --height 1080 --repeats 30]

One 1920x1080 frame of the paper's model (Lambertian + Beckmann specular, light co-located
with the camera), from depth and normals. In the same run: the machine's memory bandwidth
(STREAM-style copy in NumPy, and an XLA streaming kernel), the renderer's bytes per pixel
(depth and three normal components read, three channels written), and its fraction of the
memory roofline. The variants are timed in interleaved rounds, so that the machine's slow
spells hit them alike; medians, best and the p90/p10 spread. Prints a table and one JSON
line per precision.
"""

import argparse
import math
import platform
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _results import emit  # noqa: E402

import ctjax  # noqa: E402

RHO, F, SIGMA = (2.4, 1.1, 0.85), (0.3, 0.3, 0.3), 0.2


def numpy_render(camera_k, depth, nx, ny, nz):
    """The same model, vectorised NumPy, one array per component (the careful way)."""
    fx, fy, cx, cy = camera_k
    h, w = depth.shape
    dtype = depth.dtype
    u = np.arange(w, dtype=dtype)[None, :]
    v = np.arange(h, dtype=dtype)[:, None]
    x = (u - cx) / fx * depth
    y = (v - cy) / fy * depth
    inv = 1 / np.sqrt(x * x + y * y + depth * depth)
    n_dot_v = -(nx * x + ny * y + nz * depth) * inv
    lit = n_dot_v > 0
    c = np.where(lit, n_dot_v, 1)
    inv_c2 = 1 / (c * c)
    d = np.exp(-(inv_c2 - 1) / SIGMA**2) * inv_c2 * inv_c2 / SIGMA**2
    spec = np.where(lit, d / (math.pi * c * c), 0)
    diffuse = np.where(lit, n_dot_v, 0) / math.pi
    return np.stack([diffuse * r + spec * f for r, f in zip(RHO, F, strict=True)], axis=-1)


def timed(fn, repeats):
    """(best, median) seconds of `repeats` calls after one warm-up call."""
    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return float(np.min(times)), float(np.median(times))


def memory_bandwidth(nbytes: int, repeats: int) -> dict:
    """Copy bandwidth (bytes read + written per second) of a buffer much larger than cache."""
    count = nbytes // 4
    src = np.ones(count, np.float32)
    dst = np.empty_like(src)
    numpy_copy = timed(lambda: np.copyto(dst, src), repeats)[0]
    x = jnp.ones(count, jnp.float32)
    stream = jax.jit(lambda a: a * 1.5 + 1.0)
    xla_stream = timed(lambda: stream(x), repeats)[0]
    return {
        "numpy_copy_gb_s": 2 * nbytes / numpy_copy / 1e9,
        "xla_stream_gb_s": 2 * nbytes / xla_stream / 1e9,
    }


def bench_precision(dtype, camera, depth64, normals64, peak, tuned, repeats) -> dict:
    pixels = camera.width * camera.height
    depth = depth64.astype(dtype)
    nx, ny, nz = (normals64[i].astype(dtype) for i in range(3))
    # Parameters stay float64: the renderer computes in the geometry's dtype regardless.
    brdf = ctjax.cook_torrance_brdf(RHO, F, SIGMA)
    light = ctjax.ColocatedLight()
    normals = ctjax.Vec3(jnp.asarray(nx), jnp.asarray(ny), jnp.asarray(nz))
    depth_j = jnp.asarray(depth)
    interleaved = jnp.asarray(np.stack([nx, ny, nz], -1))
    k = tuple(dtype(float(getattr(camera, a))) for a in ("fx", "fy", "cx", "cy"))
    runs = {
        "ctjax": lambda: ctjax.render(brdf, light, camera, normals, depth_j),
        "ctjax_interleaved_input": lambda: ctjax.render(brdf, light, camera, interleaved, depth_j),
        "numpy": lambda: numpy_render(k, depth, nx, ny, nz),
    }
    start = time.perf_counter()
    image = jax.block_until_ready(runs["ctjax"]())
    compile_s = time.perf_counter() - start
    assert image.dtype == dtype, image.dtype
    reference = runs["numpy"]()
    error = float(np.max(np.abs(np.asarray(image) - reference)))
    # Interleaved rounds, so that a slow spell of the machine hits every variant alike.
    times = {name: [] for name in runs}
    for fn in runs.values():
        jax.block_until_ready(fn())
    for round_ in range(repeats):
        for name, fn in runs.items():
            if name.startswith("numpy") and round_ % 3:
                continue  # NumPy is slow and steady: every third round
            start = time.perf_counter()
            jax.block_until_ready(fn())
            times[name].append(time.perf_counter() - start)
    median = {name: float(np.median(t)) for name, t in times.items()}
    best = {name: float(np.min(t)) for name, t in times.items()}
    spread = {name: float(np.percentile(t, 90) / np.percentile(t, 10)) for name, t in times.items()}
    bytes_per_pixel = 7 * np.dtype(dtype).itemsize  # depth + 3 normal components, 3 channels
    roofline_s = pixels * bytes_per_pixel / peak
    row = {
        "benchmark": "render",
        "dtype": np.dtype(dtype).name,
        "width": camera.width,
        "height": camera.height,
        "bytes_per_pixel": bytes_per_pixel,
        "bandwidth_gb_s": peak / 1e9,
        "compile_s": compile_s,
        "max_abs_difference_vs_numpy": error,
        "malloc_tuned": tuned,
    }
    for name in runs:
        row[f"{name}_mpix_s_median"] = pixels / median[name] / 1e6
        row[f"{name}_mpix_s_best"] = pixels / best[name] / 1e6
        row[f"{name}_p90_over_p10"] = spread[name]
    row["speedup_vs_numpy_median"] = median["numpy"] / median["ctjax"]
    row["roofline_fraction_median"] = roofline_s / median["ctjax"]
    row["roofline_fraction_best"] = roofline_s / best["ctjax"]
    print(
        f"{row['dtype']} ({len(times['ctjax'])} timed calls each, NumPy "
        f"{len(times['numpy'])}; Mpix/s median, best, p90/p10):"
    )
    for name in runs:
        print(
            f"  {name:24s} {row[f'{name}_mpix_s_median']:6.0f} {row[f'{name}_mpix_s_best']:6.0f}"
            f"  {spread[name]:.2f}"
        )
    print(
        f"  ctjax: {row['speedup_vs_numpy_median']:.1f}x NumPy (medians), roofline "
        f"{100 * row['roofline_fraction_median']:.0f}% median "
        f"({100 * row['roofline_fraction_best']:.0f}% best) at {bytes_per_pixel} B/pixel"
    )
    print(f"  compile {compile_s:.2f} s; max |ctjax - NumPy| {error:.1e}")
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--height", type=int, default=1080)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--no-malloc-tuning", action="store_true")
    parser.add_argument(
        "--no-xla-tuning", action="store_true", help="XLA's default vector width (ctjax.tune_xla)"
    )
    args = parser.parse_args()
    tuned = False if args.no_malloc_tuning else ctjax.tune_malloc()
    wide = False if args.no_xla_tuning else ctjax.tune_xla()  # as the command line does

    w, h = args.width, args.height
    camera = ctjax.Camera(w, h, 0.8 * w, 0.8 * w, (w - 1) / 2, (h - 1) / 2)
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    depth64 = 60 + 5 * np.sin(u / 97.0) * np.cos(v / 71.0) + rng.uniform(0, 0.01, (h, w))
    normals64 = rng.normal(0, 0.25, (3, h, w))
    normals64[2] = -1
    normals64 /= np.linalg.norm(normals64, axis=0)

    bandwidth = memory_bandwidth(256 << 20, 10)  # 8x the L3 cache of a typical server core
    peak = max(bandwidth.values()) * 1e9
    print(
        f"{platform.processor() or platform.machine()}, {jax.device_count()} JAX device(s), "
        f"malloc tuned: {tuned}, 512-bit vectors (tune_xla): {wide}"
    )
    print(
        f"memory bandwidth: NumPy copy {bandwidth['numpy_copy_gb_s']:.1f} GB/s, "
        f"XLA stream {bandwidth['xla_stream_gb_s']:.1f} GB/s (roofline uses the larger)"
    )

    results = [
        {
            **bench_precision(dtype, camera, depth64, normals64, peak, tuned, args.repeats),
            "xla_tuned": wide,
        }
        for dtype in (np.float32, np.float64)
    ]
    for row in results:
        emit(row)


if __name__ == "__main__":
    main()
