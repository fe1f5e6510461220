"""The renderer against a plain NumPy reference, and its transformations."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import cast, reference_paper_image, unit, vec3, wavy_surface

import ctjax
from ctjax import Camera, ColocatedLight, PointLight, cook_torrance_brdf

CAMERA = Camera(48, 40, 45.0, 46.0, 23.5, 19.5)
RHO, F, SIGMA = [1.5, 0.6, 0.5], [0.3, 0.3, 0.25], 0.22


@pytest.fixture(scope="module")
def surface():
    return wavy_surface(CAMERA)


def test_matches_numpy_reference_of_the_paper(surface):
    depth, normals = surface
    image = ctjax.render(
        cook_torrance_brdf(RHO, F, SIGMA),
        ColocatedLight(),
        CAMERA,
        jnp.asarray(normals),
        jnp.asarray(depth),
    )
    reference = reference_paper_image(CAMERA, depth, normals, RHO, F, SIGMA)
    assert image.shape == (CAMERA.height, CAMERA.width, 3)
    np.testing.assert_allclose(np.asarray(image), reference, rtol=1e-10, atol=1e-12)


def test_points_and_depth_agree(surface):
    depth, normals = surface
    brdf = cook_torrance_brdf(RHO, F, SIGMA)
    u, v = np.meshgrid(np.arange(CAMERA.width), np.arange(CAMERA.height))
    points = np.stack([(u - 23.5) / 45.0 * depth, (v - 19.5) / 46.0 * depth, depth], axis=-1)
    by_depth = ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth)
    by_points = ctjax.render(brdf, ColocatedLight(), CAMERA, normals, points=points)
    by_vec3 = ctjax.render(brdf, ColocatedLight(), CAMERA, vec3(normals), points=vec3(points))
    np.testing.assert_allclose(np.asarray(by_depth), np.asarray(by_points), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(by_depth), np.asarray(by_vec3), rtol=1e-12)


def _point_light_reference(depth, normals, position, exponent, reference_mm):
    """Lambertian + paper specular under an offset point light with both falloffs (NumPy)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    p = np.stack([(u - 23.5) / 45.0 * depth, (v - 19.5) / 46.0 * depth, depth], -1)
    view = unit(-p)
    to_light = np.asarray(position) - p
    light = unit(to_light)
    distance2 = np.sum(to_light**2, -1)
    cos_axis = np.sum(unit(p - position) * np.array([0, 0, 1.0]), -1)
    irradiance = (reference_mm**2 / distance2) * np.maximum(cos_axis, 0) ** exponent
    half = unit(light + view)
    nl, nv, nh = (np.sum(normals * x, -1) for x in (light, view, half))
    tan2 = (1 - nh**2) / nh**2
    d = np.exp(-tan2 / SIGMA**2) / (SIGMA**2 * nh**4)
    lit = (nl > 0) & (nv > 0)
    diffuse = np.where(lit, nl, 0) / math.pi
    spec = np.where(lit, d / (math.pi * nl * nv), 0)
    return irradiance[..., None] * (diffuse[..., None] * RHO + spec[..., None] * np.asarray(F))


def test_offset_light_with_falloffs_matches_reference(surface):
    depth, normals = surface
    position = np.array([6.0, -3.0, 1.0])
    light = PointLight(position, falloff=(ctjax.InverseSquare(50.0), ctjax.SpotFalloff(3.0)))
    image = ctjax.render(cook_torrance_brdf(RHO, F, SIGMA), light, CAMERA, normals, depth)
    reference = _point_light_reference(depth, normals, position, 3.0, 50.0)
    np.testing.assert_allclose(np.asarray(image), reference, rtol=1e-9, atol=1e-12)


def test_effects_apply_in_order(surface):
    depth, normals = surface
    brdf = cook_torrance_brdf(RHO, F, SIGMA)
    plain = np.asarray(ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth))
    effects = (ctjax.Ambient([0.02, 0.03, 0.04]), ctjax.CameraGamma(2.2))
    image = ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth, effects=effects)
    expected = (plain + np.array([0.02, 0.03, 0.04])) ** (1 / 2.2)
    np.testing.assert_allclose(np.asarray(image), expected, rtol=1e-10)


def test_columns_are_the_linear_design_matrix(surface):
    depth, normals = surface
    brdf = ctjax.BRDF(
        ctjax.Lambertian(RHO),
        ctjax.Specular(F, ctjax.Beckmann(0.1)),
        ctjax.Specular([0.1, 0.1, 0.1], ctjax.Beckmann(0.4)),
    )
    light = PointLight([3.0, 0.0, 0.0], falloff=(ctjax.InverseSquare(),))
    columns = ctjax.render_columns(brdf, light, CAMERA, normals, depth)
    image = ctjax.render(brdf, light, CAMERA, normals, depth)
    assert columns.shape == (CAMERA.height, CAMERA.width, 3)
    np.testing.assert_allclose(np.asarray(columns @ brdf.weights), np.asarray(image), rtol=1e-12)


def test_light_field_equal_to_view_reproduces_colocated(surface):
    depth, normals = surface
    u, v = np.meshgrid(np.arange(CAMERA.width), np.arange(CAMERA.height))
    p = np.stack([(u - 23.5) / 45.0 * depth, (v - 19.5) / 46.0 * depth, depth], -1)
    field = ctjax.LightField(unit(-p))
    brdf = cook_torrance_brdf(RHO, F, SIGMA)
    by_field = ctjax.render(brdf, field, CAMERA, normals, depth)
    colocated = ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth)
    np.testing.assert_allclose(np.asarray(by_field), np.asarray(colocated), rtol=1e-9)
    theta, phi = ctjax.lights.angles_from_direction(jnp.asarray(unit(-p)))
    by_angles = ctjax.render(brdf, ctjax.LightField.from_angles(theta, phi), CAMERA, normals, depth)
    np.testing.assert_allclose(np.asarray(by_angles), np.asarray(colocated), rtol=1e-9)


def test_vmap_of_shade_equals_render(surface):
    depth, normals = surface
    brdf = cook_torrance_brdf(RHO, F, SIGMA)
    image = np.asarray(ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth))
    depth, normals = jnp.asarray(depth), jnp.asarray(normals)
    rows, cols = np.array([0, 5, 17, 39]), np.array([0, 30, 11, 47])

    def one(r, c):
        pixel = (c.astype(float), r.astype(float))
        point = CAMERA.backproject(pixel, depth[r, c])
        return ctjax.shade(brdf, ColocatedLight(), point, vec3(normals[r, c]), pixel)

    per_pixel = [
        np.asarray(one(jnp.asarray(r), jnp.asarray(c))) for r, c in zip(rows, cols, strict=True)
    ]
    np.testing.assert_allclose(np.stack(per_pixel), image[rows, cols], rtol=1e-12)
    batched = jax.vmap(one)(jnp.asarray(rows), jnp.asarray(cols))
    np.testing.assert_allclose(np.asarray(batched), image[rows, cols], rtol=1e-12)


@pytest.mark.parametrize(
    "lobes, with_effects, dtype",
    # Packed as: one real array; one complex; a complex and a real (validity third); two complex.
    [
        (1, False, jnp.float32),
        (2, False, jnp.float64),
        (2, True, jnp.float32),
        (3, True, jnp.float64),
    ],
)
def test_every_pixel_is_shade_whatever_the_lobes_and_effects(surface, lobes, with_effects, dtype):
    # The renderer packs the lobes' columns two to a complex number (and the validity with
    # them when effects follow): odd and even counts, invalid pixels 0 even after an ambient.
    depth, normals = (np.array(a) for a in surface)
    depth[3, 4], depth[5, 6], normals[7, 8] = np.nan, -1.0, np.nan
    parts = [
        ctjax.Lambertian(RHO),
        ctjax.Specular(F, ctjax.Beckmann(0.15)),
        ctjax.Specular([0.1, 0.2, 0.1], ctjax.Beckmann(0.4)),
    ]
    brdf = cast(ctjax.BRDF(*parts[:lobes]), dtype)
    light = cast(PointLight([3.0, 1.0, 0.0], falloff=(ctjax.InverseSquare(),)), dtype)
    effects = (ctjax.Ambient([0.02, 0.03, 0.04]), ctjax.CameraGamma(2.2)) if with_effects else ()
    depth, normals = jnp.asarray(depth, dtype), jnp.asarray(normals, dtype)
    image = np.asarray(ctjax.render(brdf, light, CAMERA, normals, depth, effects=effects))
    assert image.dtype == dtype

    def one(r, c):
        pixel = (c.astype(dtype), r.astype(dtype))
        point = CAMERA.backproject(pixel, depth[r, c])
        normal = vec3(normals[r, c])
        return ctjax.shade(brdf, light, point, normal, pixel, cast(effects, dtype))

    rows, cols = np.meshgrid(np.arange(CAMERA.height), np.arange(CAMERA.width), indexing="ij")
    expected = np.array(jax.vmap(one)(jnp.asarray(rows.ravel()), jnp.asarray(cols.ravel())))
    expected = expected.reshape(image.shape)
    for r, c in [(3, 4), (5, 6), (7, 8)]:
        assert np.all(image[r, c] == 0)
        expected[r, c] = 0
    tol = 1e-4 if dtype == jnp.float32 else 1e-12  # float32: rounding on sharp highlights
    np.testing.assert_allclose(image, expected, rtol=tol, atol=tol * 1e-2)


def test_jit_equals_no_jit(surface):
    depth, normals = surface
    brdf = cook_torrance_brdf(RHO, F, SIGMA)
    with jax.disable_jit():
        eager = ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth)
    jitted = ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth)
    np.testing.assert_allclose(np.asarray(eager), np.asarray(jitted), rtol=1e-12)


def test_float32_agrees_with_float64(surface):
    depth, normals = surface
    brdf = cook_torrance_brdf(RHO, F, SIGMA)
    light = PointLight([4.0, 1.0, 0.0], falloff=(ctjax.InverseSquare(), ctjax.SpotFalloff(2.0)))
    wide = ctjax.render(brdf, light, CAMERA, normals, depth)
    narrow = ctjax.render(
        cast(brdf, jnp.float32),
        cast(light, jnp.float32),
        CAMERA,
        jnp.asarray(normals, jnp.float32),
        jnp.asarray(depth, jnp.float32),
    )
    assert narrow.dtype == jnp.float32 and wide.dtype == jnp.float64
    np.testing.assert_allclose(np.asarray(narrow), np.asarray(wide), rtol=2e-4, atol=1e-6)


def test_gradients_with_respect_to_parameters_and_light(surface):
    depth, normals = surface

    def loss(params):
        sigma, position = params
        brdf = cook_torrance_brdf(RHO, F, sigma)
        light = PointLight(position, falloff=(ctjax.InverseSquare(),))
        return jnp.sum(ctjax.render(brdf, light, CAMERA, normals, depth) ** 2)

    params = (jnp.asarray(0.25), jnp.asarray([2.0, -1.0, 0.5]))
    grad_sigma, grad_position = jax.grad(loss)(params)
    eps = 1e-6
    fd = (loss((params[0] + eps, params[1])) - loss((params[0] - eps, params[1]))) / (2 * eps)
    assert float(grad_sigma) == pytest.approx(float(fd), rel=1e-5)
    for k in range(3):
        step = jnp.zeros(3).at[k].set(eps)
        fd = (loss((params[0], params[1] + step)) - loss((params[0], params[1] - step))) / (2 * eps)
        assert float(grad_position[k]) == pytest.approx(float(fd), rel=1e-5, abs=1e-8)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_invalid_geometry_renders_zero_with_finite_gradients(surface, dtype):
    depth, normals = (np.array(a) for a in surface)
    depth[3, 4] = np.nan
    depth[5, 6] = -1.0
    normals[7, 8] = np.nan
    normals[9, 10] = unit([0.0, 0.3, 1.0])  # facing away from the camera
    normals[11, 12] = unit([1.0, 0.0, 1e-7])  # grazing
    depth, normals = jnp.asarray(depth, dtype), jnp.asarray(normals, dtype)

    def loss(sigma, normals, depth):
        brdf = cast(cook_torrance_brdf(RHO, F, sigma), dtype)
        return jnp.sum(ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth))

    image = ctjax.render(
        cast(cook_torrance_brdf(RHO, F, SIGMA), dtype), ColocatedLight(), CAMERA, normals, depth
    )
    image = np.asarray(image)
    for r, c in [(3, 4), (5, 6), (7, 8), (9, 10)]:
        assert np.all(image[r, c] == 0)
    assert np.all(np.isfinite(image))
    grads = jax.grad(loss, argnums=(0, 1, 2))(jnp.asarray(SIGMA, dtype), normals, depth)
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g)))


def test_render_rejects_bad_shapes(surface):
    depth, normals = surface
    brdf = cook_torrance_brdf(RHO, F, SIGMA)
    with pytest.raises(ctjax.ParameterError, match="normals"):
        ctjax.render(brdf, ColocatedLight(), CAMERA, normals[:-1], depth)
    with pytest.raises(ctjax.ParameterError, match="depth"):
        ctjax.render(brdf, ColocatedLight(), CAMERA, normals, depth[:, :-1])
    with pytest.raises(ctjax.ParameterError, match="exactly one"):
        ctjax.render(brdf, ColocatedLight(), CAMERA, normals)
