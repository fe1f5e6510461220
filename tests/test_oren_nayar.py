"""Oren-Nayar's rough diffuse lobe (`ctjax/lobes/oren_nayar.py`): its formula against the
paper's angles, its limits, and its candidate."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import random_hemisphere, vec3

from ctjax import Lambertian, paper_model
from ctjax.lobes.oren_nayar import OrenNayar, OrenNayarCandidate


def _oren_nayar_by_angles(roughness, n, l, v):
    """Oren & Nayar (1994), the qualitative model, written with the angles of incidence and
    view and their azimuths: `cos t_i (A + B max(0, cos(phi_i - phi_r)) sin a tan b) / pi`."""
    s2 = roughness**2
    a = 1 - 0.5 * s2 / (s2 + 0.33)
    b = 0.45 * s2 / (s2 + 0.09)
    theta_i, theta_r = math.acos(n @ l), math.acos(n @ v)
    tangent_l, tangent_v = l - (n @ l) * n, v - (n @ v) * n
    norms = np.linalg.norm(tangent_l) * np.linalg.norm(tangent_v)
    cos_phi = tangent_l @ tangent_v / norms if norms > 1e-12 else 0.0
    alpha, beta = max(theta_i, theta_r), min(theta_i, theta_r)
    return (
        math.cos(theta_i) * (a + b * max(0.0, cos_phi) * math.sin(alpha) * math.tan(beta)) / math.pi
    )


def test_the_lobe_is_oren_nayars_model_and_lambertian_at_roughness_0():
    rng = np.random.default_rng(0)
    normal = random_hemisphere(rng, 200, min_cos=0.2)
    light = np.array([random_hemisphere(rng, 1, around=m, min_cos=0.05)[0] for m in normal])
    view = np.array([random_hemisphere(rng, 1, around=m, min_cos=0.05)[0] for m in normal])
    for roughness in (0.0, 0.3, 1.1):
        lobe = OrenNayar([1.0, 1.0, 1.0], roughness)
        got = np.asarray(jax.vmap(lobe.radiance)(vec3(normal), vec3(light), vec3(view)))
        want = [_oren_nayar_by_angles(roughness, *x) for x in zip(normal, light, view, strict=True)]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    directions = (vec3(normal), vec3(light), vec3(view))
    smooth = jax.vmap(OrenNayar(1.0, 0.0).radiance)(*directions)
    lambertian = jax.vmap(Lambertian(1.0).radiance)(*directions)
    np.testing.assert_allclose(np.asarray(smooth), np.asarray(lambertian), rtol=1e-12)


def test_with_the_light_at_the_lens_the_shading_is_flatter_than_the_cosine():
    """L = V: `(A cos t + B sin^2 t) / pi`: relative to facing the scope, a wall at 60
    degrees is brighter than Lambert's cosine says, the more so the rougher."""
    n = jnp.asarray([0.0, 0.0, 1.0])
    at = lambda lobe, t: float(  # noqa: E731
        lobe.radiance(n, *(2 * (jnp.asarray([math.sin(t), 0.0, math.cos(t)]),)))
    )
    ratios = [
        at(OrenNayar(1.0, s), math.radians(60)) / at(OrenNayar(1.0, s), 0.0)
        for s in (0.0, 0.5, 1.1)
    ]
    assert ratios[0] == pytest.approx(0.5)
    assert ratios[0] < ratios[1] < ratios[2]
    s2 = 0.25
    a, b = 1 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)
    t = math.radians(60)
    assert at(OrenNayar(1.0, 0.5), t) == pytest.approx(
        (a * math.cos(t) + b * math.sin(t) ** 2) / math.pi
    )


def test_the_candidate_roughens_the_diffuse_lobe_only_and_keeps_it_the_albedo_maps():
    from ctjax.fitting._map_least_squares import diffuse_lobe

    model = paper_model(1.0, 0.3, 0.2)
    starts = OrenNayarCandidate()(model, {})
    assert [float(m.brdf.lobes[0].roughness) for m in starts] == [0.3, 0.8]
    for start in starts:
        assert isinstance(start.brdf.lobes[0], OrenNayar)
        assert type(start.brdf.lobes[1]) is type(model.brdf.lobes[1])  # the specular lobe
        assert diffuse_lobe(start) == 0  # its weight is the per-point albedo
        np.testing.assert_array_equal(start.brdf.weights, model.brdf.weights)
    assert OrenNayarCandidate()(starts[0], {}) == []  # already rough


def test_a_negative_roughness_is_refused():
    from ctjax import CtjaxError

    with pytest.raises(CtjaxError, match="roughness"):
        OrenNayar(1.0, -0.1)
    with pytest.raises(CtjaxError, match="oren-nayar"):
        OrenNayarCandidate().synthesize(paper_model(1.0, 0.3, 0.2), -1.0, {})
