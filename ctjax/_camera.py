import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._convert import as_float, check_finite, check_positive, check_shape
from ._errors import ParameterError
from ._typing import Array, Float, Pixel, Scalar
from ._vector import Vec3

# OpenCV's distortion coefficients, in its order: the five of its default model, then the
# rational model's three (its CALIB_RATIONAL_MODEL; a da Vinci's calibration has all eight).
DISTORTION_KEYS = ("k1", "k2", "p1", "p2", "k3")
RATIONAL_KEYS = ("k4", "k5", "k6")


class Camera(eqx.Module):
    """Pinhole camera from intrinsics, OpenCV conventions.

    Camera frame: x right, y down, z forward, mm. Pixel (u, v) = (column, row); the centre of
    pixel (i, j) is at u = j, v = i (integer coordinates, as in OpenCV's `K`).

    **Arguments:**

    - `width`, `height`: image size in pixels.
    - `fx`, `fy`: focal lengths in pixels (> 0); `cx`, `cy`: principal point in pixels.
    - `distortion`: OpenCV's (k1, k2, p1, p2, k3), or its rational model's (k1, k2, p1, p2,
      k3, k4, k5, k6), or None. Images are undistorted on load (`ctjax.load_capture`), after
      which the camera has no distortion.
    """

    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)
    fx: Float[Array, ""] = eqx.field(converter=as_float)
    fy: Float[Array, ""] = eqx.field(converter=as_float)
    cx: Float[Array, ""] = eqx.field(converter=as_float)
    cy: Float[Array, ""] = eqx.field(converter=as_float)
    distortion: Float[Array, "5"] | Float[Array, "8"] | None = None

    def __check_init__(self):
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ParameterError(
                f"Camera width and height must be positive, got {self.width}x{self.height}"
            )
        for name in ("fx", "fy", "cx", "cy"):
            check_shape("Camera", name, getattr(self, name), ())
            check_finite("Camera", name, getattr(self, name))
        check_positive("Camera", "fx", self.fx)
        check_positive("Camera", "fy", self.fy)
        if self.distortion is not None:
            if np.shape(self.distortion) != (8,):
                check_shape("Camera", "distortion", self.distortion, (5,))
            check_finite("Camera", "distortion", self.distortion)

    @property
    def intrinsic_matrix(self) -> Float[Array, "3 3"]:
        """OpenCV's K."""
        zero, one = jnp.zeros_like(self.fx), jnp.ones_like(self.fx)
        return jnp.stack(
            [
                jnp.stack([self.fx, zero, self.cx]),
                jnp.stack([zero, self.fy, self.cy]),
                jnp.stack([zero, zero, one]),
            ]
        )

    def backproject(self, pixel: Pixel, depth: Scalar) -> Vec3:
        """The camera-frame point (mm) at `depth` (its z, mm) along pixel (u, v)'s ray."""
        u, v = pixel
        # Reciprocals of the (unbatched) intrinsics: one division per image, not per pixel.
        return Vec3(
            depth * (u - self.cx) * (1 / self.fx), depth * (v - self.cy) * (1 / self.fy), depth
        )

    def project(self, point: Vec3) -> Pixel:
        """Pixel (u, v) of a camera-frame point (no distortion)."""
        return (self.fx * point.x / point.z + self.cx, self.fy * point.y / point.z + self.cy)

    def to_json(self) -> dict:
        out = {
            "width": int(self.width),
            "height": int(self.height),
            **{k: float(getattr(self, k)) for k in ("fx", "fy", "cx", "cy")},
        }
        if self.distortion is not None:
            terms = map(float, np.asarray(self.distortion))
            out.update(zip((*DISTORTION_KEYS, *RATIONAL_KEYS), terms, strict=False))
        return out

    def without_distortion(self) -> "Camera":
        return Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy)
