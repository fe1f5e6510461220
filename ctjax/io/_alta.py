"""Measured BRDF data in ALTA's text format (https://alta.gitlabpages.inria.fr).

Header lines start with `#`: `#DIM n_in n_out`, `#PARAM_IN NAME`, optional `#PARAM_OUT NAME`
(and comments such as `#SAMPLE`, `#URL`, `#VS`); then one sample per line, `n_in` input
coordinates and `n_out` values. Supported input parametrisations (angles in radians,
theta from the normal, phi azimuth):

- `ISOTROPIC_TL_TV_PROJ_DPHI`: theta_l, theta_v cos(dphi), theta_v sin(dphi)
- `ISOTROPIC_TV_TL_DPHI`: theta_v, theta_l, dphi
- `SPHERICAL_TL_PL_TV_PV`: theta_l, phi_l, theta_v, phi_v
- `CARTESIAN`: L (x, y, z), V (x, y, z)
- `RUSIN_TH_TD_PD`: theta_h, theta_d, phi_d (isotropic Rusinkiewicz)
- `RUSIN_TH_PH_TD_PD`: theta_h, phi_h, theta_d, phi_d

Output: `INV_STERADIAN` (the BRDF, 1/sr) or `INV_STERADIAN_COSINE_FACTOR` (the BRDF times
cos theta_l). A file without `#PARAM_OUT` is taken to be `INV_STERADIAN`, ALTA's usual
meaning for BRDF data (say otherwise with `param_out=`).
"""

import dataclasses
from pathlib import Path

import numpy as np

from .._errors import CtjaxError

OUTPUTS = ("INV_STERADIAN", "INV_STERADIAN_COSINE_FACTOR")


@dataclasses.dataclass(frozen=True)
class MeasuredBRDF:
    """Samples of a measured BRDF: unit light and view directions in the surface frame
    (normal +z), the measured values (N, C), and what they are (`param_out`)."""

    light: np.ndarray  # (N, 3)
    view: np.ndarray  # (N, 3)
    values: np.ndarray  # (N, C)
    param_in: str
    param_out: str
    header: dict

    def __len__(self) -> int:
        return len(self.values)


def _spherical(theta, phi):
    return np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1
    )


def _rotate_y(v, angle):
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    x, y, z = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    return np.concatenate([c * x + s * z, y, -s * x + c * z], axis=-1)


def _rotate_z(v, angle):
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    x, y, z = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    return np.concatenate([c * x - s * y, s * x + c * y, z], axis=-1)


def _from_rusinkiewicz(theta_h, phi_h, theta_d, phi_d):
    """(L, V) from Rusinkiewicz's half/difference angles."""
    light = _spherical(theta_d, phi_d)
    view = _spherical(theta_d, phi_d + np.pi)
    light = _rotate_z(_rotate_y(light, theta_h), phi_h)
    view = _rotate_z(_rotate_y(view, theta_h), phi_h)
    return light, view


def _directions(param_in: str, x: np.ndarray):
    zero = np.zeros(len(x))
    if param_in == "ISOTROPIC_TL_TV_PROJ_DPHI":
        theta_v, dphi = np.hypot(x[:, 1], x[:, 2]), np.arctan2(x[:, 2], x[:, 1])
        return _spherical(x[:, 0], zero), _spherical(theta_v, dphi)
    if param_in == "ISOTROPIC_TV_TL_DPHI":
        return _spherical(x[:, 1], zero), _spherical(x[:, 0], x[:, 2])
    if param_in == "SPHERICAL_TL_PL_TV_PV":
        return _spherical(x[:, 0], x[:, 1]), _spherical(x[:, 2], x[:, 3])
    if param_in == "CARTESIAN":
        light, view = x[:, :3], x[:, 3:6]
        return (
            light / np.linalg.norm(light, axis=1, keepdims=True),
            view / np.linalg.norm(view, axis=1, keepdims=True),
        )
    if param_in == "RUSIN_TH_TD_PD":
        return _from_rusinkiewicz(x[:, 0], zero, x[:, 1], x[:, 2])
    if param_in == "RUSIN_TH_PH_TD_PD":
        return _from_rusinkiewicz(x[:, 0], x[:, 1], x[:, 2], x[:, 3])
    raise AssertionError(param_in)


_INPUT_DIMS = {
    "ISOTROPIC_TL_TV_PROJ_DPHI": 3,
    "ISOTROPIC_TV_TL_DPHI": 3,
    "SPHERICAL_TL_PL_TV_PV": 4,
    "CARTESIAN": 6,
    "RUSIN_TH_TD_PD": 3,
    "RUSIN_TH_PH_TD_PD": 4,
}


def load_alta(path: str | Path, *, param_out: str | None = None) -> MeasuredBRDF:
    """Read an ALTA data file; rejects malformed files with one `CtjaxError` naming the
    file and the line."""
    path = Path(path)
    if not path.is_file():
        raise CtjaxError(f"{path}: ALTA file not found")
    header: dict[str, str] = {}
    rows = []
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise CtjaxError(f"{path}: not a text file") from None
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, _, value = stripped[1:].partition(" ")
            header[key.upper()] = value.strip()
            continue
        try:
            rows.append([float(v) for v in stripped.split()])
        except ValueError:
            raise CtjaxError(f"{path}:{number}: non-numeric data line: {stripped[:60]!r}") from None
    if "DIM" not in header:
        raise CtjaxError(f"{path}: missing #DIM line")
    try:
        n_in, n_out = (int(v) for v in header["DIM"].split())
    except ValueError:
        raise CtjaxError(
            f"{path}: malformed #DIM {header['DIM']!r} (expected two integers)"
        ) from None
    param_in = header.get("PARAM_IN", "").upper()
    if param_in not in _INPUT_DIMS:
        raise CtjaxError(
            f"{path}: unknown or missing #PARAM_IN {param_in or '(none)'}; supported: "
            + ", ".join(_INPUT_DIMS)
        )
    if _INPUT_DIMS[param_in] != n_in:
        raise CtjaxError(
            f"{path}: #PARAM_IN {param_in} has {_INPUT_DIMS[param_in]} inputs, #DIM says {n_in}"
        )
    output = (param_out or header.get("PARAM_OUT") or "INV_STERADIAN").upper()
    if output not in OUTPUTS:
        raise CtjaxError(
            f"{path}: unsupported #PARAM_OUT {output}; supported: {', '.join(OUTPUTS)}"
        )
    if not rows:
        raise CtjaxError(f"{path}: no data lines")
    widths = {len(r) for r in rows}
    if widths != {n_in + n_out}:
        raise CtjaxError(
            f"{path}: data lines must have {n_in + n_out} numbers (#DIM {n_in} {n_out})"
        )
    data = np.asarray(rows, np.float64)
    if not np.all(np.isfinite(data)):
        raise CtjaxError(f"{path}: non-finite numbers in the data")
    light, view = _directions(param_in, data[:, :n_in])
    return MeasuredBRDF(light, view, data[:, n_in:], param_in, output, header)
