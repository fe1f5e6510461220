"""The paper's per-pixel coefficients of eq. (4) (the samples themselves are built by
`ctjax.observations`)."""

import numpy as np

from ..observations import ShadingSamples as ShadingSamples
from ..observations import colocated_samples as colocated_samples
from ..observations import concatenate as concatenate
from ..observations import view_directions as view_directions


def paper_coefficients(samples: ShadingSamples):
    """The per-pixel coefficients of the paper's eq. (4), as NumPy arrays (N,):

    `I = a rho + b F sigma^-2 exp(-c / sigma^2)`, a = (N.L) E / pi,
    b = E / (pi (N.L)(N.V) cos^4 alpha), c = tan^2 alpha, E the irradiance factor.
    """
    n, l, v = (
        np.asarray(getattr(samples, k).to_array(), np.float64) for k in ("normal", "light", "view")
    )
    irradiance = np.asarray(samples.irradiance, np.float64)
    half = l + v
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    n_dot_l, n_dot_v = np.sum(n * l, -1), np.sum(n * v, -1)
    cos2 = np.sum(n * half, -1) ** 2
    a = irradiance * n_dot_l / np.pi
    b = irradiance / (np.pi * n_dot_l * n_dot_v * cos2 * cos2)
    c = (1 - cos2) / cos2
    return a, b, c
