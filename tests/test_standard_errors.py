"""`ctjax.fitting.standard_errors`: the Gauss-Newton standard errors of a pixel fit."""

import jax.numpy as jnp
import numpy as np
import pytest

import ctjax
from ctjax.fitting import fit_model, pixel_predict, predictions, standard_errors
from ctjax.observations import PixelSamples


def _samples(values, normal, point):
    n = len(values)
    return PixelSamples(
        ctjax.Vec3.from_array(jnp.asarray(point)),
        ctjax.Vec3.from_array(jnp.asarray(normal)),
        (jnp.zeros(n), jnp.zeros(n)),
        jnp.asarray(values),
        jnp.zeros(n, int),
        jnp.zeros(n, int),
        jnp.zeros(n, int),
    )


def test_a_linear_fits_standard_errors_are_least_squares_own():
    """A Lambertian surface under the light at the lens is linear in rho_tilde: its
    standard errors are ordinary least squares' s^2 (X^T X)^-1, s^2 over the joint fit."""
    rng = np.random.default_rng(0)
    n = 300
    tilt = rng.uniform(0, 1.2, n)
    turn = rng.uniform(0, 2 * np.pi, n)
    normal = np.stack([np.sin(tilt) * np.cos(turn), np.sin(tilt) * np.sin(turn), -np.cos(tilt)], 1)
    point = np.stack([rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(40, 60, n)], 1)
    truth = ctjax.ShadingModel(
        ctjax.BRDF(ctjax.Lambertian([0.5, 0.4, 0.3])), ctjax.ColocatedLight()
    )
    clean = np.asarray(predictions(truth, _samples(np.zeros((n, 3)), normal, point), pixel_predict))
    values = clean + rng.normal(0, 0.01, clean.shape)
    samples = _samples(values, normal, point)
    fit = fit_model(truth, samples, pixel_predict)
    errors = standard_errors(fit.model, samples, pixel_predict)["brdf.lobes[0].weight"]

    design = clean / np.asarray([0.5, 0.4, 0.3])  # the prediction per unit rho_tilde
    rho = np.sum(design * values, 0) / np.sum(design * design, 0)
    variance = np.sum((values - design * rho) ** 2) / (values.size - 3)
    np.testing.assert_allclose(errors, np.sqrt(variance / np.sum(design * design, 0)), rtol=1e-6)
    # About the noise's: 0.01 / sqrt(sum a^2).
    assert errors[0] == pytest.approx(0.01 / np.sqrt(np.sum(design[:, 0] ** 2)), rel=0.1)


def test_a_parameter_the_data_leave_alone_has_none():
    """sigma with no specular weight: its Jacobian column is 0, its standard error None."""
    rng = np.random.default_rng(1)
    n = 200
    normal = np.tile([0.0, 0.0, -1.0], (n, 1)) + rng.normal(0, 0.2, (n, 3)) * [1, 1, 0]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    point = np.stack([rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), np.full(n, 50.0)], 1)
    model = ctjax.paper_model(0.5, 0.0, 0.3)
    clean = np.asarray(predictions(model, _samples(np.zeros((n, 3)), normal, point), pixel_predict))
    samples = _samples(clean + rng.normal(0, 0.01, clean.shape), normal, point)
    errors = standard_errors(model, samples, pixel_predict)
    assert errors["brdf.lobes[1].distribution.sigma"] is None
