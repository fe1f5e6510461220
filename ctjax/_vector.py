"""`Vec3`: a 3-vector as three scalars, so that `vmap` gives one array per component.

Physics in ctjax is written for one pixel and batched by `jax.vmap`. Batched (3,)-arrays
become (pixels, 3) arrays, which XLA on CPU vectorises along the 3 components: 6-7x slower
than one array per component. A `Vec3` is a pytree of three scalars, so the same one-pixel
code batches into three (pixels,) arrays. It reads like an array: `a @ b` is the dot product,
`a + b`, `a - b`, `-a`, `s * a`, `a / s` work as expected.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._convert import on_device
from ._typing import Array, Float


class Vec3(eqx.Module):
    """A 3-vector (camera frame unless said otherwise) stored as three scalars (or arrays)."""

    x: Array
    y: Array
    z: Array

    @classmethod
    def from_array(cls, a: Float[Array, "... 3"]) -> "Vec3":
        if isinstance(a, jax.core.Tracer):
            return cls(a[..., 0], a[..., 1], a[..., 2])
        # Concrete arrays are split on the host: eager slicing compiles a program per shape.
        a = np.asarray(a)
        return cls(*(on_device(a[..., i]) for i in range(3)))

    def to_array(self) -> Float[Array, "... 3"]:
        return jnp.stack([self.x, self.y, self.z], axis=-1)

    def __add__(self, other: "Vec3") -> "Vec3":
        return Vec3(self.x + other.x, self.y + other.y, self.z + other.z)

    def __sub__(self, other: "Vec3") -> "Vec3":
        return Vec3(self.x - other.x, self.y - other.y, self.z - other.z)

    def __neg__(self) -> "Vec3":
        return Vec3(-self.x, -self.y, -self.z)

    def __mul__(self, scale) -> "Vec3":
        return Vec3(self.x * scale, self.y * scale, self.z * scale)

    __rmul__ = __mul__

    def __truediv__(self, scale) -> "Vec3":
        return self * (1 / scale)

    def __matmul__(self, other: "Vec3") -> Array:
        return self.x * other.x + self.y * other.y + self.z * other.z

    def cross(self, other: "Vec3") -> "Vec3":
        return Vec3(
            self.y * other.z - self.z * other.y,
            self.z * other.x - self.x * other.z,
            self.x * other.y - self.y * other.x,
        )


def where(condition, a: Vec3, b: Vec3) -> Vec3:
    """Component-wise `jnp.where` for Vec3."""
    return jax.tree_util.tree_map(lambda p, q: jnp.where(condition, p, q), a, b)


def tangent_basis(axis: Vec3) -> tuple[Vec3, Vec3]:
    """Two unit vectors orthogonal to the unit `axis` and to each other."""
    # Any vector not parallel to the axis will do: x, unless the axis is close to it.
    use_x = jnp.abs(axis.x) < 0.9
    zero, one = jnp.zeros_like(axis.x), jnp.ones_like(axis.x)
    helper = Vec3(jnp.where(use_x, one, zero), jnp.where(use_x, zero, one), zero)
    first = helper - axis * (helper @ axis)
    first = first / jnp.sqrt(first @ first)
    return first, axis.cross(first)


def tangent_direction(start: Vec3, y) -> Vec3:
    """The unit direction at tangent-plane coordinates `y` (2,) around the unit `start`
    (y = 0: `start`; |y| is the tangent of the angle to it). A chart without the poles of
    spherical angles, for fitting a direction (a light, a normal) near a starting one."""
    first, second = tangent_basis(start)
    direction = start + first * y[0] + second * y[1]
    return direction / jnp.sqrt(direction @ direction)
