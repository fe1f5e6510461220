"""Every free parameter of a model, and a reparametrisation that keeps it physical.

Parameters are the floating-point array fields of the model's equinox Modules, found by
walking the pytree. Each field may declare its domain in its metadata (`POSITIVE`,
`UNIT_INTERVAL`, `domain(lo, hi)`, `FIXED`; see `ctjax._convert`); the fitters then work on
unconstrained values: `lo + softplus(u)` for (lo, inf), `lo + (hi - lo) sigmoid(u)` for a
bounded interval, the identity otherwise. A lobe or effect written by a user is fitted the
same way; without metadata its fields are free and unconstrained.
"""

import dataclasses
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from .._convert import strongly_typed as strongly_typed

# How far inside its domain an unknown at the domain's end is taken (its unconstrained
# value then finite): 1e-9, or the dtype's resolution where that is coarser (float32:
# 1 - 1e-9 is 1, whose logit is infinite; a knee's slope at 1 was, and DenseLM's small-step
# test read every step as small, 2026-12-06).
_EPS = 1e-9


def _eps(value) -> float:
    return max(_EPS, float(jnp.finfo(jnp.result_type(value, float)).eps))


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One free array field: how to reach it in the model, its name and domain."""

    get: Callable
    name: str
    domain: tuple[float, float]
    per_frame: bool = False


def _walk(node, get, name, out, freeze):
    if isinstance(node, eqx.Module):
        for field in dataclasses.fields(node):
            if field.metadata.get("static", False):
                continue
            value = getattr(node, field.name)
            child_get = (lambda g, n: lambda m: getattr(g(m), n))(get, field.name)
            child_name = f"{name}.{field.name}" if name else field.name
            declared = field.metadata.get("domain", (-math.inf, math.inf))
            if declared == "fixed" or freeze(child_name):
                continue
            if eqx.is_array(value):
                if jnp.issubdtype(value.dtype, jnp.floating):
                    per_frame = bool(field.metadata.get("per_frame", False))
                    out.append(Parameter(child_get, child_name, declared, per_frame))
            else:
                _walk(value, child_get, child_name, out, freeze)
    elif isinstance(node, tuple | list):
        for index, value in enumerate(node):
            child_get = (lambda g, i: lambda m: g(m)[i])(get, index)
            _walk(value, child_get, f"{name}[{index}]", out, freeze)


def free_parameters(model, freeze: Callable[[str], bool] = lambda name: False) -> list[Parameter]:
    """The free parameters of `model`, in a fixed order, with dotted names
    (e.g. `brdf.lobes[k].distribution.sigma`). `freeze(name)` can hold more fixed."""
    out: list[Parameter] = []
    _walk(model, lambda m: m, "", out, freeze)
    return out


def per_frame_names(model) -> list[str]:
    """The names of `model`'s free parameters with one value per frame (`PER_FRAME`)."""
    return [p.name for p in free_parameters(model) if p.per_frame]


def _to_unconstrained(value, domain):
    lo, hi = domain
    if math.isfinite(lo) and math.isfinite(hi):
        eps = _eps(value)
        p = jnp.clip((value - lo) / (hi - lo), eps, 1 - eps)
        return jnp.log(p) - jnp.log1p(-p)
    if math.isfinite(lo):
        excess = jnp.maximum(value - lo, _EPS)
        # inverse softplus, stable for large values
        return excess + jnp.log(-jnp.expm1(-excess))
    if math.isfinite(hi):
        deficit = jnp.maximum(hi - value, _EPS)
        return -(deficit + jnp.log(-jnp.expm1(-deficit)))
    return value


def _from_unconstrained(u, domain):
    lo, hi = domain
    if math.isfinite(lo) and math.isfinite(hi):
        return lo + (hi - lo) * jax.nn.sigmoid(u)
    # softplus underflows to 0 below u = -745 (float64): a fit driven to the domain's edge
    # stays inside it, not on it (a GGX alpha of exactly 0 is refused by the lobe).
    if math.isfinite(lo):
        return lo + jnp.maximum(jax.nn.softplus(u), jnp.finfo(jnp.result_type(u)).tiny)
    if math.isfinite(hi):
        return hi - jnp.maximum(jax.nn.softplus(-u), jnp.finfo(jnp.result_type(u)).tiny)
    return u


def unconstrained(model, parameters: list[Parameter]) -> list:
    """The unconstrained values of `parameters` in `model`."""
    return [_to_unconstrained(p.get(model), p.domain) for p in parameters]


def constrained(model, parameters: list[Parameter], values: list):
    """`model` with `parameters` set from unconstrained `values`."""
    if not parameters:
        return model
    return eqx.tree_at(
        lambda m: [p.get(m) for p in parameters],
        model,
        [_from_unconstrained(v, p.domain) for v, p in zip(values, parameters, strict=True)],
    )


def as_vector(model, parameters: list[Parameter]) -> tuple[jnp.ndarray, Callable]:
    """The values of `parameters` in `model`, in their own units (not the fitters'
    reparametrisation), as one vector, and the function that puts such a vector back into
    `model`: what a Jacobian in the parameters' own units (a covariance) is taken over."""
    values = [jnp.asarray(p.get(model)) for p in parameters]
    shapes = [v.shape for v in values]
    flat = jnp.concatenate([v.reshape(-1) for v in values])

    def rebuilt(theta):
        parts, start = [], 0
        for shape in shapes:
            size = math.prod(shape)
            parts.append(theta[start : start + size].reshape(shape))
            start += size
        return eqx.tree_at(lambda m: [p.get(m) for p in parameters], model, parts)

    return flat, rebuilt
