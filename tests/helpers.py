"""Shared test helpers: tolerance comparisons, random directions, a NumPy reference model."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ctjax import Camera, Vec3


def cast(tree, dtype):
    """Every floating array leaf of a pytree (a model, a Vec3...) cast to `dtype`."""

    def leaf(x):
        if eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.floating):
            return x.astype(dtype)
        return x

    return jax.tree_util.tree_map(leaf, tree)


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_hemisphere(rng, n, around=(0.0, 0.0, 1.0), min_cos=0.05):
    """Random unit vectors with cos(angle to `around`) >= min_cos."""
    around = unit(around)
    out = []
    while len(out) < n:
        v = unit(rng.normal(size=(4 * n, 3)))
        out.extend(v[v @ around >= min_cos])
    return np.asarray(out[:n])


def vec3(a) -> Vec3:
    return Vec3.from_array(jnp.asarray(a))


def finite_difference(f, x, eps=1e-6):
    """Central finite-difference gradient of scalar f at array x (float64)."""
    x = np.asarray(x, np.float64)
    grad = np.zeros_like(x)
    for i in np.ndindex(x.shape):
        step = np.zeros_like(x)
        step[i] = eps
        grad[i] = (float(f(x + step)) - float(f(x - step))) / (2 * eps)
    return grad


def reference_paper_image(camera: Camera, depth, normals, rho, F, sigma):
    """The paper's eq. (1)-(2) under a co-located light, written plainly in NumPy."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    x = (u - float(camera.cx)) / float(camera.fx) * depth
    y = (v - float(camera.cy)) / float(camera.fy) * depth
    p = np.stack([x, y, depth], -1)
    view = -p / np.linalg.norm(p, axis=-1, keepdims=True)
    n_dot_v = np.sum(normals * view, -1)
    cos_a = n_dot_v  # L = V, so H = V and alpha = angle(N, V)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tan2 = (1 - cos_a**2) / cos_a**2
        d = np.exp(-tan2 / sigma**2) / (sigma**2 * cos_a**4)
        spec = d / (math.pi * n_dot_v * n_dot_v)
    lit = n_dot_v > 0
    diffuse = np.where(lit, n_dot_v, 0) / math.pi
    spec = np.where(lit, spec, 0)
    return diffuse[..., None] * np.asarray(rho) + spec[..., None] * np.asarray(F)


def wavy_surface(camera: Camera, seed=0):
    """Depth (H, W) and unit normals (H, W, 3) of a smooth analytic surface facing the camera."""
    rng = np.random.default_rng(seed)
    h, w = camera.height, camera.width
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    a, b = rng.uniform(0.02, 0.05, 2)
    depth = 60 + 4 * np.sin(a * u) * np.cos(b * v) + 0.02 * (u - w / 2)
    # Normals of the depth map's surface, analytically: P(u, v) = depth * K^-1 (u, v, 1).
    du = 4 * a * np.cos(a * u) * np.cos(b * v) + 0.02
    dv = -4 * b * np.sin(a * u) * np.sin(b * v)
    fx, fy, cx, cy = (float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy))
    ray = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], -1)
    dpu = du[..., None] * ray + depth[..., None] * np.array([1 / fx, 0, 0])
    dpv = dv[..., None] * ray + depth[..., None] * np.array([0, 1 / fy, 0])
    n = unit(np.cross(dpv, dpu))
    n[np.sum(n * ray, -1) > 0] *= -1
    return depth, n


def command_error(argv, capsys) -> tuple[int, list[str]]:
    """Run `ctjax ARGV` in this process as the console would, for a command that should
    fail: its status and its stderr's lines, with every Python warning it raised turned
    into a failure (a separate process would print them to stderr, beside the one line).
    The process-level path (`python -m ctjax.cli`, its exit status, no traceback at exit) is
    test_cli.py's subprocess test; one command there costs an import of JAX, ~5 s."""
    import warnings

    from ctjax.cli import main

    capsys.readouterr()
    with warnings.catch_warnings(record=True) as raised:
        warnings.simplefilter("always")
        status = main(list(argv))
    assert not raised, [str(w.message) for w in raised]
    return status, capsys.readouterr().err.strip().splitlines()
