"""Field converters and checks shared by every Module (lobes, lights, effects, camera).

Checks run only on concrete values: inside `jit`/`vmap` the fields are tracers and the
checks are skipped (the fitters keep parameters in their domain by reparametrisation).
"""

import jax
import jax.numpy as jnp
import numpy as np

from ._errors import ParameterError
from ._typing import Array, Float


def on_device(x, dtype=None) -> Array:
    """`jnp.asarray(x, dtype)` without an eager JAX operation where `x` is host data (a
    NumPy array or scalar, nested lists): since JAX 0.10 `jnp.asarray` of host data compiles
    a program (`lax.stage`) per shape and dtype, 10-60 ms each in a new process (2500 of the
    test suite's compilations were such small programs), where `jax.device_put` of the NumPy
    array copies it. The dtype is canonicalised as `jnp.asarray` does (float64 -> float32
    without `jax_enable_x64`); the result is not weakly typed. JAX arrays and tracers go
    through `jnp.asarray`."""
    if isinstance(x, jax.Array):  # tracers too
        return jnp.asarray(x, dtype)
    host = np.asarray(x, dtype)
    return jax.device_put(host.astype(jax.dtypes.canonicalize_dtype(host.dtype), copy=False))


def as_float(x) -> Float[Array, "..."]:
    """`jnp.asarray`, promoting integers and bools to the default float dtype."""
    # Python scalars and host arrays without an eager JAX op (`jnp.asarray` of one, or
    # `astype`, compiles a program: milliseconds each in a new process), with the same
    # dtype and weak type.
    if isinstance(x, float):
        return jax.device_put(x)
    if isinstance(x, np.ndarray | np.generic | int):  # host data (bool is an int)
        host = np.asarray(x)
        if not np.issubdtype(host.dtype, np.floating):
            host = host.astype(jax.dtypes.canonicalize_dtype(float))
        return on_device(host)
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(float)


def as_rgb(x) -> Float[Array, "3"]:
    """A per-channel quantity: a scalar is broadcast to the three channels (on the host
    where it is host data: no eager JAX op)."""
    if isinstance(x, np.ndarray | np.generic | int) and np.ndim(x) == 0:
        x = np.broadcast_to(x, (3,))
    x = as_float(x)
    return jnp.broadcast_to(x, (3,)) if x.ndim == 0 else x


def concrete(x) -> np.ndarray | None:
    if isinstance(x, jax.core.Tracer):
        return None
    try:
        return np.asarray(x)
    except Exception:  # e.g. abstract shape structs
        return None


def check_shape(owner: str, name: str, x, shape: tuple[int, ...]) -> None:
    if jnp.shape(x) != shape:
        raise ParameterError(f"{owner}.{name} must have shape {shape}, got {jnp.shape(x)}")


def check_finite(owner: str, name: str, x) -> None:
    value = concrete(x)
    if value is not None and not np.all(np.isfinite(value)):
        raise ParameterError(f"{owner}.{name} must be finite, got {value}")


def check_positive(owner: str, name: str, x, *, allow_zero: bool = False) -> None:
    check_finite(owner, name, x)
    value = concrete(x)
    if value is None:
        return
    bad = np.any(value < 0) if allow_zero else np.any(value <= 0)
    if bad:
        kind = "non-negative" if allow_zero else "positive"
        raise ParameterError(f"{owner}.{name} must be {kind}, got {value}")


def cast_floating(tree, dtype):
    """Every floating-point array leaf of a pytree (a model, a camera...) cast to `dtype`.

    The renderer computes in the dtype of the geometry it is given: float64 parameters
    must not silently turn a float32 render into a float64 one (2x the memory traffic).
    The cast is differentiable.
    """

    def leaf(x):
        if isinstance(x, jax.Array | np.ndarray) and jnp.issubdtype(x.dtype, jnp.floating):
            return jnp.asarray(x, dtype)
        return x

    return jax.tree_util.tree_map(leaf, tree)


def strongly_typed(tree):
    """`tree` with its floating-point JAX arrays strongly typed, in their own dtype.

    A Python float makes a weakly typed array (`jnp.asarray(0.2)`), which `jit` compiles
    apart from a strongly typed one of the same dtype: models mixing the two (a start and
    its copies with new values) would compile every fitter twice.
    """

    def leaf(x):
        if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.inexact):
            return jnp.asarray(x, x.dtype)
        return x

    return jax.tree_util.tree_map(leaf, tree)


# Parameter domains, declared where each field is defined (`eqx.field(metadata=...)`), so
# that the fitters keep every parameter physical by reparametrisation without a registry:
# a new lobe or effect declares its own. Fields without a domain are free and unconstrained.
def domain(lo: float = -float("inf"), hi: float = float("inf")) -> dict:
    """Field metadata: the parameter lives in the open interval (lo, hi)."""
    return {"domain": (float(lo), float(hi))}


POSITIVE = domain(0.0)
UNIT_INTERVAL = domain(0.0, 1.0)
# Held fixed by the fitters (normalisations, directions, intensities the paper folds into
# the weights).
FIXED = {"domain": "fixed"}
# One value per frame of the capture (an exposure): each frame's own nuisance. A model fitted
# on some frames knows nothing of another's, so the held-out protocol fits these on the
# held-out frames themselves (`ctjax.heldout`), everything else held.
PER_FRAME = {"per_frame": True}


def named(name: str, metadata: dict | None = None) -> dict:
    """Field metadata: the parameter's name in the paper's words (`rho_tilde`, `F_tilde`,
    `sigma`, `offset_mm`...), under which every estimator's JSON shows it (`ctjax.to_json`),
    with `metadata` (a domain) kept. A new lobe names its own parameters this way."""
    return {**(metadata or {}), "name": name}
