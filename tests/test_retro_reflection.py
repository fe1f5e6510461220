"""The retro-reflection lobe (`ctjax/lobes/retro_reflection.py`): its physics, that the
fitters, the JSON and the diagnostics use it with no other edit, and that it explains the
CEA's measured retro-reflective tape."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ctjax
from ctjax.diagnostics import CANDIDATES
from ctjax.fitting import brdf_columns, brdf_predict, fit_model, measured_samples
from ctjax.io import load_alta
from ctjax.lobes.retro_reflection import RetroReflection

RETRO = Path(__file__).resolve().parents[2] / "shared" / "data" / "retro-gray-tape.dat"


def _directions(degrees):
    theta = np.radians(degrees)
    return ctjax.Vec3.from_array(jnp.asarray([np.sin(theta), 0.0, np.cos(theta)]))


def test_peak_at_the_light_falls_with_angle_and_incidence():
    lobe = RetroReflection(1.0, 1e-3, 2.0)
    normal = ctjax.Vec3.from_array(jnp.asarray([0.0, 0.0, 1.0]))
    light = _directions(30.0)
    at_light = float(lobe.radiance(normal, light, light))
    # At L = V the peak is the incidence cosine to the power falloff + 1.
    assert at_light == pytest.approx(np.cos(np.radians(30.0)) ** 3, rel=1e-9)
    # 2.6 degrees away (1 - cos = 1e-3): one width, a factor e lower (up to the cosine).
    aside = float(lobe.radiance(normal, light, _directions(30.0 + np.degrees(np.arccos(1 - 1e-3)))))
    assert aside == pytest.approx(at_light / np.e, rel=1e-3)
    # Unlit or unseen: exactly 0, with finite gradients.
    below = _directions(95.0)
    assert float(lobe.radiance(normal, below, light)) == 0.0
    grad = jax.grad(lambda l: l.radiance(normal, below, light))(lobe)
    assert all(np.all(np.isfinite(g)) for g in jax.tree_util.tree_leaves(grad))


def test_bad_parameters_are_one_clear_error():
    with pytest.raises(ctjax.ParameterError, match=r"RetroReflection\.width must be positive"):
        RetroReflection(1.0, 0.0)
    with pytest.raises(ctjax.ParameterError, match=r"RetroReflection\.weight must be non-neg"):
        RetroReflection(-1.0, 1e-3)


def test_json_and_diagnostics_see_it_with_no_edit():
    brdf = ctjax.BRDF(ctjax.Lambertian(0.5), RetroReflection(0.2, 1e-3, 1.0))
    named = ctjax.named_parameters(brdf)
    assert named["rho_tilde"] == [0.5] * 3 and named["retro"] == pytest.approx([0.2] * 3)
    assert named["retro_width"] == pytest.approx(1e-3)
    assert ctjax.to_json(brdf)["lobes"][1]["class"] == "RetroReflection"
    candidate = next(c for c in CANDIDATES if c.name == "retro_reflection")
    starts = candidate(ctjax.paper_model(), {})
    assert len(starts) == 2
    assert all(isinstance(m.brdf.lobes[-1], RetroReflection) for m in starts)


def test_it_halves_the_error_of_cook_torrance_on_measured_data():
    """CEA's retro-reflective tape: measured 6.31 -> 1.47 1/sr."""
    samples = measured_samples(load_alta(RETRO))
    cook_torrance = [
        ctjax.BRDF(
            ctjax.Lambertian(0.5),
            ctjax.CookTorrance(0.5, ctjax.Beckmann(s), (ctjax.GeometricAttenuation(),)),
        )
        for s in (0.05, 0.2, 0.5)
    ]
    fit = dict(columns=brdf_columns, scale=1.0, unit="1/sr", refine=3)
    base = fit_model(cook_torrance, samples, brdf_predict, **fit)
    starts = [
        ctjax.BRDF(*base.model.lobes, RetroReflection(1.0, w, k))
        for w in (1e-4, 1e-3, 1e-2)
        for k in (1.0, 5.0)
    ]
    retro = fit_model(starts, samples, brdf_predict, **fit)
    assert retro.unit == "1/sr"
    assert retro.calibration_rmse <= 0.5 * base.calibration_rmse
    width = ctjax.named_parameters(retro.model)["retro_width"]
    assert 1e-4 < width < 1e-2
