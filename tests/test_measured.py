"""Measured BRDF data: the ALTA loader (the retro-reflection lobe fitted to real data is in
`test_retro_reflection.py`)."""

from pathlib import Path

import numpy as np
import pytest

import ctjax
from ctjax.io import load_alta

RETRO = Path(__file__).resolve().parents[2] / "shared" / "data" / "retro-gray-tape.dat"


def test_retro_gray_tape_loads():
    data = load_alta(RETRO)
    assert len(data) == 7405 and data.values.shape == (7405, 1)
    assert data.param_in == "ISOTROPIC_TL_TV_PROJ_DPHI" and data.param_out == "INV_STERADIAN"
    np.testing.assert_allclose(np.linalg.norm(data.light, axis=1), 1)
    np.testing.assert_allclose(np.linalg.norm(data.view, axis=1), 1)
    incidence = np.degrees(np.arccos(data.light[:, 2]))
    np.testing.assert_allclose(np.unique(np.round(incidence, 6)), [15, 30, 60])
    # The largest value is measured in the retro direction (V = L).
    peak = np.argmax(data.values[:, 0])
    np.testing.assert_allclose(data.light[peak], data.view[peak], atol=1e-9)


def _write(path, header, rows):
    path.write_text("\n".join([*header, *(" ".join(f"{v:.17g}" for v in r) for r in rows)]))
    return path


def _random_directions(seed, n=50):
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0, 1.4, (n, 2))
    phi = rng.uniform(-np.pi, np.pi, (n, 2))
    light = np.stack(
        [
            np.sin(theta[:, 0]) * np.cos(phi[:, 0]),
            np.sin(theta[:, 0]) * np.sin(phi[:, 0]),
            np.cos(theta[:, 0]),
        ],
        -1,
    )
    view = np.stack(
        [
            np.sin(theta[:, 1]) * np.cos(phi[:, 1]),
            np.sin(theta[:, 1]) * np.sin(phi[:, 1]),
            np.cos(theta[:, 1]),
        ],
        -1,
    )
    return theta, phi, light, view


def test_parametrisations_give_the_same_directions(tmp_path):
    theta, phi, light, view = _random_directions(0)
    values = np.arange(len(theta))[:, None] * 1.0
    dphi = phi[:, 1] - phi[:, 0]
    # Isotropic: rotate so that phi_l = 0.
    rotated_view = np.stack(
        [
            np.sin(theta[:, 1]) * np.cos(dphi),
            np.sin(theta[:, 1]) * np.sin(dphi),
            np.cos(theta[:, 1]),
        ],
        -1,
    )
    rotated_light = np.stack([np.sin(theta[:, 0]), 0 * theta[:, 0], np.cos(theta[:, 0])], -1)
    cases = {
        "SPHERICAL_TL_PL_TV_PV": (
            np.stack([theta[:, 0], phi[:, 0], theta[:, 1], phi[:, 1]], -1),
            light,
            view,
        ),
        "CARTESIAN": (np.concatenate([light, view], -1), light, view),
        "ISOTROPIC_TV_TL_DPHI": (
            np.stack([theta[:, 1], theta[:, 0], dphi], -1),
            rotated_light,
            rotated_view,
        ),
        "ISOTROPIC_TL_TV_PROJ_DPHI": (
            np.stack([theta[:, 0], theta[:, 1] * np.cos(dphi), theta[:, 1] * np.sin(dphi)], -1),
            rotated_light,
            rotated_view,
        ),
    }
    for name, (inputs, expected_light, expected_view) in cases.items():
        path = _write(
            tmp_path / f"{name}.dat",
            [f"#DIM {inputs.shape[1]} 1", f"#PARAM_IN {name}"],
            np.concatenate([inputs, values], -1),
        )
        data = load_alta(path)
        np.testing.assert_allclose(data.light, expected_light, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(data.view, expected_view, atol=1e-12, err_msg=name)


def test_rusinkiewicz_round_trip(tmp_path):
    # theta_h = 0 and phi_d = 0: L and V symmetric about the normal in the x-z plane.
    rows = [[0.0, 0.3, 0.0, 1.0]]
    data = load_alta(_write(tmp_path / "r.dat", ["#DIM 3 1", "#PARAM_IN RUSIN_TH_TD_PD"], rows))
    np.testing.assert_allclose(data.light[0], [np.sin(0.3), 0, np.cos(0.3)], atol=1e-12)
    np.testing.assert_allclose(data.view[0], [-np.sin(0.3), 0, np.cos(0.3)], atol=1e-12)


@pytest.mark.parametrize(
    "header, rows, message",
    [
        (["#DIM 3 1", "#PARAM_IN NOT_A_PARAM"], [[0, 0, 0, 1]], "unknown or missing #PARAM_IN"),
        (["#DIM 3 1"], [[0, 0, 0, 1]], "unknown or missing #PARAM_IN"),
        (["#PARAM_IN CARTESIAN"], [[0, 0, 1, 0, 0, 1, 1]], "missing #DIM"),
        (["#DIM 3 1", "#PARAM_IN RUSIN_TH_TD_PD"], [[0, 0, 1]], "must have 4 numbers"),
        (
            ["#DIM 3 1", "#PARAM_IN RUSIN_TH_TD_PD", "#PARAM_OUT RGB_COLOR"],
            [[0, 0, 0, 1]],
            "PARAM_OUT",
        ),
        (["#DIM 4 1", "#PARAM_IN RUSIN_TH_TD_PD"], [[0, 0, 0, 0, 1]], "has 3 inputs"),
        (["#DIM 3 1", "#PARAM_IN RUSIN_TH_TD_PD"], [], "no data lines"),
    ],
)
def test_bad_alta_files(tmp_path, header, rows, message):
    with pytest.raises(ctjax.CtjaxError, match=message):
        load_alta(_write(tmp_path / "bad.dat", header, rows))


def test_non_numeric_line_names_the_line(tmp_path):
    path = tmp_path / "bad.dat"
    path.write_text("#DIM 3 1\n#PARAM_IN RUSIN_TH_TD_PD\n0 0 0 1\n0 0 zero 1\n")
    with pytest.raises(ctjax.CtjaxError, match=r"bad.dat:4: non-numeric"):
        load_alta(path)
    with pytest.raises(ctjax.CtjaxError, match="not found"):
        load_alta(tmp_path / "missing.dat")
