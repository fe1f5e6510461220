import equinox as eqx
import interpax
import jax.numpy as jnp

from .._convert import FIXED, as_float
from .._errors import ParameterError
from .._numerics import safe_normalize
from .._typing import Array, Float, Pixel, Scalar
from .._vector import Vec3
from ._light import AbstractFalloff, AbstractLight


def direction_from_angles(theta, phi):
    """The paper's eq. (7): `L = (sin phi cos theta, sin phi sin theta, cos phi)`.

    theta in [-pi, pi] is the tilt, phi in [0, pi/2] the slant from the optical axis.
    """
    return jnp.stack(
        [jnp.sin(phi) * jnp.cos(theta), jnp.sin(phi) * jnp.sin(theta), jnp.cos(phi)], axis=-1
    )


def angles_from_direction(direction):
    """Inverse of `direction_from_angles`: (theta, phi) of unit direction(s) `(..., 3)`."""
    x, y, z = direction[..., 0], direction[..., 1], direction[..., 2]
    return jnp.arctan2(y, x), jnp.arctan2(jnp.hypot(x, y), z)


class LightField(AbstractLight):
    """A per-pixel light direction field (paper eq. 7): the light's direction seen from the
    surface point imaged at each pixel, in the camera frame, with unit irradiance.

    Directions are stored at pixel centres and interpolated between them component-wise
    (interpax, then renormalised), which avoids the wrap-around of the tilt angle.

    **Arguments:**

    - `directions`: unit light directions, shape (H, W, 3), camera frame.
    - `method`: interpax interpolation method between pixel centres (default "cubic").
    - `falloff`: irradiance factors of the surface point's position seen from the camera
      centre (e.g. `InverseSquare`; the light is taken to be near the lens for them, as
      `ColocatedLight` does); default none, the paper's unit irradiance.
    """

    directions: Float[Array, "H W 3"] = eqx.field(converter=as_float, metadata=FIXED)
    method: str = eqx.field(static=True, default="cubic")
    falloff: tuple[AbstractFalloff, ...] = ()

    def __check_init__(self):
        if self.directions.ndim != 3 or self.directions.shape[-1] != 3:
            raise ParameterError(
                f"LightField.directions must have shape (H, W, 3), got {self.directions.shape}"
            )

    @classmethod
    def from_angles(cls, theta, phi, method: str = "cubic", falloff=()) -> "LightField":
        """A field from the paper's tilt `theta` and slant `phi` maps, each (H, W)."""
        return cls(
            direction_from_angles(as_float(theta), as_float(phi)), method=method, falloff=falloff
        )

    def illuminate(self, point: Vec3, view: Vec3, pixel: Pixel) -> tuple[Vec3, Scalar]:
        del view
        height, width, _ = self.directions.shape
        rows = jnp.arange(height, dtype=self.directions.dtype)
        cols = jnp.arange(width, dtype=self.directions.dtype)
        u, v = pixel
        value = interpax.interp2d(
            v[None],
            u[None],
            rows,
            cols,
            self.directions,
            method=self.method,
            extrap=True,
            even_spacing=True,
        )[0]
        irradiance = jnp.ones((), self.directions.dtype)
        for effect in self.falloff:
            irradiance = irradiance * effect(point)
        return safe_normalize(Vec3.from_array(value)), irradiance
