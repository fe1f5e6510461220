"""Oren-Nayar's rough diffuse lobe: a Lambertian surface made of V-cavities.

Tissue is not a Lambertian reflector: light scattered under the surface and a rough
surface both flatten its shading, so that a wall seen at 60 degrees is brighter than the
cosine law says. Oren and Nayar (SIGGRAPH 1994, their qualitative model) describe a
surface of Lambertian V-cavities whose slopes have a standard deviation `roughness`
(radians): with the light at the lens (L = V) its radiance is `(A cos t + B sin^2 t) / pi`
instead of `cos t / pi`, t the angle of incidence. No lobe of the paper's model, and no
image effect, flattens the shading this way (a camera gamma compresses every value, an
ambient term adds the same to each). Noisy normals look flatter too: a fit on normals that
differ from frame to frame takes a roughness the surface does not have (5 degrees RMS:
0.44 on a Lambertian synthetic capture), which is why the tracks give each surface point
one normal (`ctjax._point_normals.one_normal_per_point`).

This file is the whole lobe: the physics for one pixel, its parameter's domain and name,
and its candidate for `ctjax diagnose` and `ctjax synth --oren-nayar`. Nothing else in
ctjax was edited to add it. It is a `Lambertian` (its weight is the albedo, `rho_tilde`,
per surface point under the albedo map) whose angular shape has one parameter.
"""

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._candidate import AbstractCandidate, with_lobes
from .._convert import as_float, check_positive, check_shape, domain, named
from .._errors import ParameterError
from .._typing import Array, Float, PyTree, Scalar
from .._vector import Vec3
from ._lambertian import Lambertian


class OrenNayar(Lambertian):
    """`rho_tilde / pi * (N.L) * (A + B max(0, L.V - (N.L)(N.V)) / max(N.L, N.V))`, with
    `A = 1 - 0.5 s^2 / (s^2 + 0.33)` and `B = 0.45 s^2 / (s^2 + 0.09)`, s the roughness:
    Oren-Nayar's qualitative model, `max(0, cos(phi_i - phi_r)) sin(alpha) tan(beta)`
    written with the three directions (alpha, beta the larger and the smaller of the angles
    of incidence and view). Roughness 0 is the Lambertian lobe. 0 unless N.L > 0 and
    N.V > 0; reciprocal.

    **Arguments:**

    - `weight`: rho_tilde per colour channel (as `Lambertian`), >= 0.
    - `roughness`: the standard deviation of the facets' slope angle, radians, >= 0
      (fitted below pi/2).
    """

    diffuse_name: ClassVar[str] = "oren-nayar"
    # Fitted inside (0, pi/2): A and B level off as the slopes steepen (at 1.1 rad A is
    # 0.61, B 0.42; the limit 0.5, 0.45), and where the data ask for the flattest shading
    # an open range let LM walk off to 3e6 rad (the shared sinus's odd frames).
    roughness: Float[Array, ""] = eqx.field(
        converter=as_float, metadata=named("oren_nayar_roughness", domain(0.0, math.pi / 2))
    )

    def __check_init__(self):
        super().__check_init__()
        check_shape("OrenNayar", "roughness", self.roughness, ())
        check_positive("OrenNayar", "roughness", self.roughness, allow_zero=True)

    def _coefficients(self):
        s2 = self.roughness * self.roughness
        return 1 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)  # A, B

    def radiance(self, normal: Vec3, light: Vec3, view: Vec3) -> Scalar:
        return self.radiance_given(self.geometry(normal, light, view))

    # The radiance is A g_A + B g_B, the roughness only in A and B: a search over the
    # roughness (the sigma BnB with `--diffuse oren-nayar`) computes the two terms once.
    def geometry(self, normal: Vec3, light: Vec3, view: Vec3) -> PyTree:
        """`(N.L / pi, N.L / pi * max(0, L.V - N.L N.V) / max(N.L, N.V))` where lit
        (N.L > 0 and N.V > 0), else 0."""
        n_dot_l, n_dot_v = normal @ light, normal @ view
        lit = (n_dot_l > 0) & (n_dot_v > 0)
        # sin(alpha) tan(beta) / (sin t_i sin t_r) = 1 / cos(beta) = 1 / max(N.L, N.V).
        larger = jnp.where(lit, jnp.maximum(n_dot_l, n_dot_v), 1.0)
        azimuth = jnp.maximum(light @ view - n_dot_l * n_dot_v, 0.0)
        cosine = jnp.where(lit, n_dot_l, 0.0) / math.pi
        return cosine, cosine * azimuth / larger

    def radiance_given(self, geometry: PyTree) -> Scalar:
        a, b = self._coefficients()
        cosine, flattening = geometry
        return a * cosine + b * flattening


def _roughened(roughness):
    def swap(lobe):
        if type(lobe) is not Lambertian:
            return lobe
        return OrenNayar(lobe.weight, jnp.asarray(roughness, jnp.result_type(lobe.weight)))

    return swap


class OrenNayarCandidate(AbstractCandidate):
    """Rough, flattened diffuse shading: the Lambertian lobe as Oren-Nayar's, from a
    moderately and a very rough start."""

    name = "oren_nayar"

    def __call__(self, model, context):
        if not any(type(lobe) is Lambertian for lobe in model.brdf.lobes):
            return []
        return [with_lobes(model, _roughened(s)) for s in (0.3, 0.8)]

    def add_synth_arguments(self, group):
        group.add_argument(
            "--oren-nayar",
            type=float,
            metavar="ROUGHNESS",
            help="Oren-Nayar's rough diffuse lobe instead of Lambertian (slope std, radians)",
        )

    def synth_value(self, args):
        return args.oren_nayar

    def synthesize(self, model, value, context):
        if not value >= 0 or not math.isfinite(value):
            raise ParameterError(f"--oren-nayar must be a roughness >= 0, got {value}")
        return with_lobes(model, _roughened(value))
