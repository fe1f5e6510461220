"""Lobe properties, parametrised over every lobe and factor ctjax ships."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import cast, finite_difference, random_hemisphere, vec3

import ctjax
from ctjax import (
    GGX,
    Beckmann,
    GeometricAttenuation,
    Lambertian,
    MultiScaleBeckmann,
    SchlickFresnel,
    Specular,
)
from ctjax.lobes.oren_nayar import OrenNayar

LOBES = {
    "lambertian": lambda: Lambertian([0.8, 0.4, 0.3]),
    "beckmann": lambda: Specular(0.3, Beckmann(0.25)),
    "beckmann_small_sigma": lambda: Specular(0.3, Beckmann(1e-3)),
    "ggx": lambda: Specular(0.3, GGX(0.25)),
    "multiscale": lambda: Specular(0.3, MultiScaleBeckmann([0.1, 0.4], [0.7, 0.3])),
    "schlick": lambda: Specular(0.3, Beckmann(0.25), (SchlickFresnel(0.04),)),
    "geometric_attenuation": lambda: Specular(0.3, Beckmann(0.25), (GeometricAttenuation(),)),
    "cook_torrance_1982": lambda: ctjax.CookTorrance(
        0.3, Beckmann(0.25), (GeometricAttenuation(),)
    ),
    "cook_torrance_full": lambda: Specular(
        0.3, GGX(0.3), (SchlickFresnel(0.02), GeometricAttenuation())
    ),
    "oren_nayar": lambda: OrenNayar([0.8, 0.4, 0.3], 0.4),
}


@pytest.fixture(params=sorted(LOBES), ids=sorted(LOBES))
def lobe(request):
    return LOBES[request.param]()


def _directions(seed, n=64):
    rng = np.random.default_rng(seed)
    normal = random_hemisphere(rng, n, min_cos=0.2)
    light = np.array([random_hemisphere(rng, 1, around=m, min_cos=0.05)[0] for m in normal])
    view = np.array([random_hemisphere(rng, 1, around=m, min_cos=0.05)[0] for m in normal])
    return normal, light, view


@eqx.filter_jit  # one program per lobe (eagerly: hundreds of one-operation programs)
def _radiance(lobe, n, l, v):
    return jax.vmap(lobe.radiance)(vec3(n), vec3(l), vec3(v))


def test_non_negative_and_zero_when_unlit(lobe):
    n, l, v = _directions(0)
    values = np.asarray(_radiance(lobe, n, l, v))
    assert np.all(np.isfinite(values)) and np.all(values >= 0)
    # Light below the surface, or a back-facing surface: exactly zero.
    assert np.all(np.asarray(_radiance(lobe, n, -l, v)) == 0)
    assert np.all(np.asarray(_radiance(lobe, n, l, -v)) == 0)


def test_reciprocity_where_declared(lobe):
    n, l, v = _directions(1)
    forward = np.asarray(_radiance(lobe, n, l, v))
    backward = np.asarray(_radiance(lobe, n, v, l))
    n_dot_l, n_dot_v = np.sum(n * l, -1), np.sum(n * v, -1)
    if lobe.reciprocal:
        np.testing.assert_allclose(forward / n_dot_l, backward / n_dot_v, rtol=1e-10, atol=1e-300)
    else:
        # The paper's specular term is symmetric in L and V as written (no N.L in front).
        np.testing.assert_allclose(forward, backward, rtol=1e-10, atol=1e-300)


def test_gradient_matches_finite_differences(lobe):
    n, l, v = _directions(2, n=4)
    params, static = jax.tree_util.tree_flatten(lobe)
    for i in range(len(n)):

        def f(x, i=i):
            return lobe.radiance(vec3(x), vec3(l[i]), vec3(v[i]))

        grad = np.asarray(jax.grad(f)(jnp.asarray(n[i])))
        np.testing.assert_allclose(grad, finite_difference(f, n[i]), rtol=1e-5, atol=1e-7)

        for k, p in enumerate(params):

            def g(x, k=k, i=i):
                leaves = list(params)
                leaves[k] = jnp.asarray(x)
                model = jax.tree_util.tree_unflatten(static, leaves)
                # Weights enter linearly; test the shape parameters through the radiance and
                # the weights through the weighted sum (BRDF).
                return ctjax.BRDF(model).radiance(vec3(n[i]), vec3(l[i]), vec3(v[i])).sum()

            grad = np.asarray(jax.grad(g)(jnp.asarray(p, float)))
            np.testing.assert_allclose(
                grad, finite_difference(g, np.asarray(p), eps=1e-7), rtol=2e-5, atol=1e-6
            )


GRAZING = {
    "n.l = 0": ([0, 0, 1], [1, 0, 0], [0, 0.6, 0.8]),
    "n.l = 1e-9": ([0, 0, 1], [1, 0, 1e-9], [0, 0.6, 0.8]),
    "n.v = 0": ([0, 0, 1], [0, 0.6, 0.8], [1, 0, 0]),
    "both grazing": ([0, 0, 1], [1, 0, 1e-7], [-1, 0, 1e-7]),
    "l = -v": ([0, 0, 1], [1, 0, 0], [-1, 0, 0]),
    "l = v grazing": ([0, 0, 1], [1, 0, 1e-8], [1, 0, 1e-8]),
    "normal incidence": ([0, 0, 1], [0, 0, 1], [0, 0, 1]),
}


@pytest.mark.parametrize("case", sorted(GRAZING), ids=sorted(GRAZING))
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_finite_values_and_gradients_at_grazing(lobe, case, dtype):
    from helpers import cast, unit

    n, l, v = (jnp.asarray(unit(x), dtype) for x in GRAZING[case])
    lobe = cast(lobe, dtype)

    def f(lobe, n, l, v):
        return ctjax.BRDF(lobe).radiance(vec3(n), vec3(l), vec3(v)).sum()

    value = f(lobe, n, l, v)
    grads = jax.grad(f, argnums=(0, 1, 2, 3))(lobe, n, l, v)
    assert np.isfinite(float(value))
    for leaf in jax.tree_util.tree_leaves(grads):
        assert np.all(np.isfinite(np.asarray(leaf))), case
    if float(n @ l) <= 0 or float(n @ v) <= 0:
        assert float(value) == 0


def test_jit_equals_no_jit(lobe):
    n, l, v = _directions(3, n=8)
    eager = _radiance(lobe, n, l, v)
    jitted = jax.jit(_radiance)(lobe, n, l, v)
    np.testing.assert_allclose(np.asarray(eager), np.asarray(jitted), rtol=1e-12)


def test_paper_specular_matches_eq_2():
    # One hand-checked value: N = V = L = z, alpha = 0: D = 1 / sigma^2, term F D / pi.
    spec = Specular(0.5, Beckmann(0.2))
    z = vec3([0.0, 0.0, 1.0])
    assert float(spec.radiance(z, z, z)) == pytest.approx(1 / 0.04 / np.pi)


def test_multiscale_with_one_scale_is_beckmann():
    n, l, v = _directions(4, n=16)
    one = _radiance(Specular(1.0, MultiScaleBeckmann([0.3], [1.0])), n, l, v)
    ref = _radiance(Specular(1.0, Beckmann(0.3)), n, l, v)
    np.testing.assert_allclose(np.asarray(one), np.asarray(ref), rtol=1e-12)


def test_brdf_is_the_sum_of_its_lobes():
    n, l, v = (vec3(x[0]) for x in _directions(5, n=1))
    a, b = Lambertian([0.5, 0.2, 0.1]), Specular([0.3, 0.3, 0.2], Beckmann(0.3))
    brdf = ctjax.BRDF(a, b)
    expected = a.weight * a.radiance(n, l, v) + b.weight * b.radiance(n, l, v)
    np.testing.assert_allclose(np.asarray(brdf.radiance(n, l, v)), np.asarray(expected))
    doubled = brdf.with_weights(2 * brdf.weights)
    np.testing.assert_allclose(
        np.asarray(doubled.radiance(n, l, v)), 2 * np.asarray(expected), rtol=1e-12
    )


@pytest.mark.parametrize(
    "make",
    [
        lambda: Beckmann(0.0),
        lambda: Beckmann(-1.0),
        lambda: Beckmann(float("nan")),
        lambda: Lambertian([0.1, float("nan"), 0.1]),
        lambda: Lambertian([0.1, 0.2]),
        lambda: Specular(-0.1, Beckmann(0.2)),
        lambda: GGX(0.0),
        lambda: SchlickFresnel(0.0),
        lambda: MultiScaleBeckmann([0.1, 0.2], [1.0]),
    ],
)
def test_bad_parameters_raise_ctjax_errors(make):
    with pytest.raises(ctjax.ParameterError):
        make()


def test_radiance_given_geometry_is_the_radiance(lobe):
    # The BnB computes each lobe's geometry once and evaluates `radiance_given` at every
    # sigma: same values and parameter gradients as `radiance`, and the geometry reads none
    # of the lobe's fields (a lobe with other parameters and weights gives the same).
    import equinox as eqx

    arrays = _directions(6, n=32)
    other = jax.tree.map(lambda x: x * 1.3 if eqx.is_inexact_array(x) else x, lobe)

    @jax.jit  # (one program: op by op this test took 5 s over the lobes)
    def both(lobe, other, n, l, v):
        geometry = jax.vmap(lobe.geometry)(n, l, v)

        def direct(lobe):
            return jnp.sum(jax.vmap(lobe.radiance)(n, l, v))

        def given(lobe):
            return jnp.sum(jax.vmap(lobe.radiance_given)(geometry))

        values = (jax.vmap(lobe.radiance)(n, l, v), jax.vmap(lobe.radiance_given)(geometry))
        gradients = (eqx.filter_grad(direct)(lobe), eqx.filter_grad(given)(lobe))
        return values, gradients, (geometry, jax.vmap(other.geometry)(n, l, v))

    values, gradients, geometries = both(lobe, other, *(vec3(x) for x in arrays))
    np.testing.assert_allclose(
        np.asarray(values[1]), np.asarray(values[0]), rtol=1e-13, atol=1e-300
    )
    np.testing.assert_allclose(
        np.asarray(values[0]), np.asarray(_radiance(lobe, *arrays)), rtol=1e-13, atol=1e-300
    )
    for a, b in zip(*(jax.tree.leaves(g) for g in gradients), strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-12, atol=1e-300)
    for a, b in zip(*(jax.tree.leaves(g) for g in geometries), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_parameter_driven_past_its_domain_stays_inside_it():
    """An unconstrained roughness of -1000 (a degenerate fit) maps to the smallest positive
    float, not to 0, which the lobe refuses (`GGX.alpha must be positive, got 0.0` ended a
    diagnosis on 100 samples)."""
    from ctjax import ShadingModel
    from ctjax.fitting import free_parameters
    from ctjax.fitting._parameters import constrained, unconstrained
    from ctjax.lights import PointLight

    model = ShadingModel(
        (Lambertian(jnp.ones(3)), Specular(jnp.ones(3), GGX(0.3))), PointLight((0.0, 0.0, 0.0))
    )
    parameters = free_parameters(model)
    values = unconstrained(model, parameters)
    index = [p.name for p in parameters].index("brdf[1].distribution.alpha")
    values[index] = jnp.asarray(-1000.0)
    alpha = constrained(model, parameters, values).brdf[1].distribution.alpha
    assert 0 < float(alpha) < 1e-300


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_a_parameter_at_its_domains_end_is_a_finite_unknown(dtype):
    """A knee's slope of 1 (a channel it leaves alone: the end of (0, 1]) is a finite
    unconstrained value in either precision (float32 read 1 - 1e-9 as 1, an infinite logit),
    and maps back to within 1e-9 of 1, or the dtype's resolution where that is coarser."""
    from ctjax import ShadingModel
    from ctjax.effects import Knee
    from ctjax.fitting import free_parameters
    from ctjax.fitting._parameters import constrained, unconstrained
    from ctjax.lights import PointLight

    model = cast(
        ShadingModel(
            (Lambertian(jnp.ones(3)), Specular(jnp.ones(3), GGX(0.3))),
            PointLight((0.0, 0.0, 0.0)),
            (Knee(0.6, (0.5, 1.0, 1.0), compressed=(True, False, False)),),
        ),
        dtype,
    )
    parameters = free_parameters(model)
    values = unconstrained(model, parameters)
    assert all(bool(jnp.all(jnp.isfinite(v))) for v in values)
    slope = constrained(model, parameters, values).effects[0].slope
    assert slope.dtype == dtype
    within = 2 * max(1e-9, float(jnp.finfo(dtype).eps))  # 1e-9 inside it, or the dtype's step
    np.testing.assert_allclose(slope, [0.5, 1.0, 1.0], rtol=within)
