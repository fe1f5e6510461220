"""Lights of several sources: the renderer sums the lobes over a light's `sources`."""

import jax.numpy as jnp
import numpy as np
import pytest

from ctjax import ParameterError, ShadingModel, Vec3, cook_torrance_brdf, shade
from ctjax.lights import InverseSquare, LightGuides, PointLight


def _vec(x, y, z):
    return Vec3(*(jnp.asarray(c, float) for c in (x, y, z)))


def _shade(light, point, normal):
    brdf = cook_torrance_brdf(0.8, 0.3, 0.2)
    return np.asarray(shade(brdf, light, point, normal, (jnp.asarray(0.0), jnp.asarray(0.0))))


def test_guides_are_point_lights_sharing_the_intensity():
    falloff = (InverseSquare(60.0),)
    point = _vec(3.0, -2.0, 55.0)
    normal = _vec(0.1 / 1.0062, 0.05 / 1.0062, -1 / 1.0062)
    one = LightGuides(4.0, 0.0, 1, falloff=falloff)
    np.testing.assert_allclose(
        _shade(one, point, normal),
        _shade(PointLight((4.0, 0.0, 0.0), falloff=falloff), point, normal),
        rtol=1e-6,
    )
    two = LightGuides(4.0, np.pi / 2, 2, falloff=falloff)
    halves = [PointLight(p, 0.5, falloff) for p in ((0.0, 4.0, 0.0), (0.0, -4.0, 0.0))]
    expected = sum(_shade(light, point, normal) for light in halves)
    np.testing.assert_allclose(_shade(two, point, normal), expected, rtol=1e-6, atol=1e-12)
    # Its one-direction summary: the total irradiance, from the lens on the axis.
    direction, irradiance = two.illuminate(_vec(0, 0, 60), _vec(0, 0, -1), (0.0, 0.0))
    np.testing.assert_allclose([direction.x, direction.y, direction.z], [0, 0, -1], atol=1e-12)
    assert float(irradiance) == pytest.approx(60.0**2 / (60.0**2 + 16.0))


def test_a_model_with_guides_renders_and_fits_like_any_light():
    model = ShadingModel(cook_torrance_brdf(0.8, 0.3, 0.2), LightGuides(5.0, 0.3, 2))
    columns = model.columns(_vec(1, 2, 50), _vec(0, 0, -1), (0.0, 0.0))
    assert columns.shape == (2,) and np.all(np.isfinite(columns))


def test_bad_guides_are_named():
    with pytest.raises(ParameterError, match="count"):
        LightGuides(4.0, 0.0, 0)
    with pytest.raises(ParameterError, match="radius_mm"):
        LightGuides(-1.0, 0.0, 2)


def test_a_light_in_the_lens_plane_is_the_point_light_at_z_0():
    """`LensPlaneLight` (calibrate-light's default offset): a `PointLight` at (x, y, 0), its
    two coordinates the fitted parameters, named apart from the free light's offset."""
    from ctjax import LensPlaneLight
    from ctjax._json import named_parameters
    from ctjax.fitting import free_parameters

    falloff = (InverseSquare(60.0),)
    point = _vec(3.0, -2.0, 55.0)
    normal = _vec(0.1 / 1.0062, 0.05 / 1.0062, -1 / 1.0062)
    plane = LensPlaneLight((4.0, -3.0), falloff=falloff)
    np.testing.assert_allclose(
        _shade(plane, point, normal),
        _shade(PointLight((4.0, -3.0, 0.0), falloff=falloff), point, normal),
        rtol=1e-12,
    )
    np.testing.assert_array_equal(plane.position_mm, [4.0, -3.0, 0.0])
    model = ShadingModel(cook_torrance_brdf(0.8, 0.3, 0.2), plane)
    assert "light.offset_mm" in {p.name for p in free_parameters(model)}
    assert named_parameters(plane)["lens_plane_offset_mm"] == [4.0, -3.0]
    with pytest.raises(ParameterError, match="offset_mm"):
        LensPlaneLight((4.0, -3.0, 0.0))


def test_the_default_light_is_made_in_the_precision_of_the_call():
    """`default_light(None)`: the paper's light made when asked for, its intensity in the
    precision then in force; a module-level default made at import held float32 where a
    user turned `jax_enable_x64` on after importing ctjax (and a kept program's key with
    it). A light given is returned as it is."""
    import jax

    from ctjax.lights import ColocatedLight
    from ctjax.lights._point import default_light

    with jax.enable_x64(False):
        assert default_light(None).intensity.dtype == jnp.float32
    with jax.enable_x64(True):
        assert default_light(None).intensity.dtype == jnp.float64
    given = ColocatedLight(2.0)
    assert default_light(given) is given
