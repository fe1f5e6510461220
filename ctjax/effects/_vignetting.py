import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_effect
from .._convert import FIXED, as_float, check_finite, check_shape, named
from .._errors import CtjaxError
from .._typing import RGB, Array, Float
from ._effect import AbstractImageEffect, Gain, Site

# The factor is kept at least this (a polynomial fitted far out could cross 0).
_FLOOR = 1e-3


class Vignetting(AbstractImageEffect):
    """The optics' radial falloff about the principal point: the radiance times
    `1 + k2 r^2 + k4 r^4`, r the pixel's distance from the principal point in focal lengths
    (the tangent of its angle off the axis), before the camera's response.

    The lens and the scope's relay optics darken the image towards its rim whatever the
    scene (Goldman's polynomial model). With the light at the lens a spot falloff cos^k of
    the same angle looks alike; this is the polynomial, and it acts wherever the light is.

    **Arguments:**

    - `k2`, `k4`: the polynomial's coefficients (0, 0: none).
    - `principal_point`: (cx, cy) in pixels; `focal_px`: (fx, fy). The camera's, held fixed.
    """

    k2: Float[Array, ""] = eqx.field(converter=as_float, metadata=named("vignetting_k2"))
    k4: Float[Array, ""] = eqx.field(converter=as_float, metadata=named("vignetting_k4"))
    principal_point: Float[Array, "2"] = eqx.field(converter=as_float, metadata=FIXED)
    focal_px: Float[Array, "2"] = eqx.field(converter=as_float, metadata=FIXED)

    def __check_init__(self):
        for name in ("k2", "k4"):
            check_shape("Vignetting", name, getattr(self, name), ())
            check_finite("Vignetting", name, getattr(self, name))
        check_shape("Vignetting", "principal_point", self.principal_point, (2,))
        check_shape("Vignetting", "focal_px", self.focal_px, (2,))

    def factor(self, pixel) -> Float[Array, ""]:
        """The falloff at pixel (u, v)."""
        x = (pixel[0] - self.principal_point[0]) / self.focal_px[0]
        y = (pixel[1] - self.principal_point[1]) / self.focal_px[1]
        r2 = x * x + y * y
        return jnp.maximum(1 + self.k2 * r2 + self.k4 * r2 * r2, _FLOOR)

    def at(self, site: Site) -> Gain:
        return Gain(self.factor(site.pixel))

    def __call__(self, rgb: RGB) -> RGB:
        raise CtjaxError("Vignetting depends on the pixel: apply `effect.at(site)`")


def _camera(context) -> tuple:
    return context["principal_point"], context["focal_px"]


class VignettingCandidate(AbstractCandidate):
    """The optics' radial falloff, from none and from a moderate one."""

    name = "vignetting"

    def __call__(self, model, context):
        if "principal_point" not in context or any(
            isinstance(effect, Vignetting) for effect in model.effects
        ):
            return []
        centre, focal = _camera(context)
        return [
            with_effect(model, Vignetting(k2, 0.0, centre, focal), first=True) for k2 in (0.0, -0.3)
        ]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--vignetting", type=float, metavar="K2", help="radial falloff 1 + K2 r^2 (r: tan)"
        )

    def synth_value(self, args):
        return args.vignetting

    def synthesize(self, model, value, context):
        centre, focal = _camera(context)
        return with_effect(model, Vignetting(value, 0.0, centre, focal), first=True)
