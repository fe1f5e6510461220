"""The lobe interface and the BRDF as a sum of lobes (the template is diffrax's MultiTerm)."""

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._typing import RGB, Array, Float, PyTree, Scalar
from .._vector import Vec3


class AbstractLobe(eqx.Module):
    """One term of a reflectance model: a linear weight per colour channel times a shape.

    `radiance(normal, light, view)` is the lobe's reflected radiance for unit weight and unit
    irradiance, **cosine factor included**, i.e. exactly the term as it appears in the paper's
    eq. (1): `N.L / pi` for the Lambertian lobe, `D / (pi (N.L)(N.V))` for the specular one.
    All three directions are unit vectors in the camera frame pointing away from the surface.
    The result must be >= 0, finite, and 0 where N.L <= 0 or N.V <= 0.

    The weight enters linearly (`rho_tilde`, `F_tilde` in the paper), so estimators can solve
    for it in closed form; every other field is a nonlinear parameter.

    `reciprocal` declares whether `radiance / (N.L)`, the BRDF proper, is symmetric in light
    and view; the property tests check it where declared.
    """

    weight: eqx.AbstractVar[Float[Array, "3"]]
    reciprocal: ClassVar[bool] = True

    @abc.abstractmethod
    def radiance(self, normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
        """Reflected radiance per unit weight and unit irradiance (cosine included)."""

    def geometry(self, normal: Vec3, light: Vec3, view: Vec3) -> PyTree:
        """What `radiance` takes of one sample's directions, whatever the lobe's parameters:
        `radiance_given(geometry(n, l, v)) == radiance(n, l, v)`, and `geometry` reads none
        of the lobe's fields (weight or nonlinear parameters).

        A search that evaluates the same samples under many parameter values (the sigma
        branch-and-bound) computes it once and passes it to `radiance_given` at every value.
        The default is the three directions; a lobe whose parameters meet the directions
        through a few scalars returns those (`Specular`: N.H and 1 / (pi N.L N.V), 2 numbers
        per sample instead of 9; `Lambertian`, which has none: its radiance).
        """
        return normal, light, view

    def radiance_given(self, geometry: PyTree) -> Scalar:
        """`radiance` from `geometry(normal, light, view)`."""
        return self.radiance(*geometry)


class BRDF(eqx.Module):
    """A reflectance model as a sum of lobes: `BRDF(Lambertian(rho), Specular(F, Beckmann(s)))`.

    The renderer and every fitter see only this interface: `columns` (one radiance per lobe,
    the design matrix of the linear weights), `weights` (K x 3) and `radiance` (RGB). A new
    lobe is a new `AbstractLobe` subclass; nothing here changes.
    """

    lobes: tuple[AbstractLobe, ...]

    def __init__(self, *lobes: AbstractLobe):
        for lobe in lobes:
            if not isinstance(lobe, AbstractLobe):
                raise TypeError(f"BRDF takes lobes (AbstractLobe), got {type(lobe).__name__}")
        if not lobes:
            raise TypeError("BRDF needs at least one lobe")
        self.lobes = tuple(lobes)

    def columns(self, normal: Vec3, light: Vec3, view: Vec3) -> Float[Array, " K"]:
        """Each lobe's radiance for unit weight: one row of the linear design matrix."""
        return jnp.stack([lobe.radiance(normal, light, view) for lobe in self.lobes])

    def geometry(self, normal: Vec3, light: Vec3, view: Vec3) -> tuple[PyTree, ...]:
        """Each lobe's `geometry`: what `columns_given` needs, whatever the parameters."""
        return tuple(lobe.geometry(normal, light, view) for lobe in self.lobes)

    def columns_given(self, geometry: tuple[PyTree, ...]) -> tuple[Scalar, ...]:
        """Each lobe's radiance for unit weight from `geometry(normal, light, view)`: the
        design row, one scalar per lobe, for searches over the nonlinear parameters."""
        return tuple(
            lobe.radiance_given(part) for lobe, part in zip(self.lobes, geometry, strict=True)
        )

    @property
    def weights(self) -> Float[Array, "K 3"]:
        """The linear weights, one row per lobe, one column per colour channel."""
        return jnp.stack([lobe.weight for lobe in self.lobes])

    def with_weights(self, weights: Float[Array, "K 3"]) -> "BRDF":
        """The same model with new linear weights (one row per lobe)."""
        return eqx.tree_at(
            lambda b: tuple(lobe.weight for lobe in b.lobes),
            self,
            tuple(weights[k] for k in range(len(self.lobes))),
        )

    def radiance(self, normal: Vec3, light: Vec3, view: Vec3) -> RGB:
        """Reflected radiance per colour channel for unit irradiance (cosine included)."""
        # An explicit sum, not `columns @ weights`: under vmap a K x 3 matmul becomes a
        # batched dot that XLA on CPU does not fuse (measured 4x slower for the image).
        return sum(lobe.weight * lobe.radiance(normal, light, view) for lobe in self.lobes)
