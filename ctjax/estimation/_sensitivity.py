"""How much the fitted specular depends on the normals where it is measured.

Where a highlight's core is clipped, sigma and F_tilde are read on the lobe's tails, and
there the specular changes fast with the angle between the normal and the half vector: for
the paper's lobe with the light at the camera, d ln(specular) / d theta = -2 tan(theta) /
(sigma^2 cos^2(theta)) + 6 tan(theta), about -20% per degree at theta = 20 degrees and
sigma = 0.25. A systematic error of the normals there (a surface too flat or too curved
around the highlights, as structure from motion leaves it) then biases the BRDF by tens of
percent (docs, "Shape from images"). This module measures that sensitivity on the fitted
model itself, for any BRDF family and light: every normal is tilted away from its half
vector by a small angle and the change of the global (non-per-point) lobes is read.
"""

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._numerics import safe_normalize
from .._programs import persistent_jit
from .._vector import tangent_basis
from ..observations import ShadingSamples
from ._branch_and_bound_map import TrackShading, track_columns

# Observations whose global lobes are at least this share of the model count (the specular
# is measured there).
SPECULAR_SHARE = 0.1


def tilted(samples: ShadingSamples, degrees: float) -> ShadingSamples:
    """`samples` with every normal turned by `degrees` away from its half vector (in the
    plane of both; about an arbitrary tangent where they coincide)."""
    normal = samples.normal
    half = safe_normalize(samples.light + samples.view)
    away = normal * (normal @ half) - half  # orthogonal to the normal, away from the half vector
    direction = safe_normalize(away, fallback=tangent_basis(normal)[0])
    angle = math.radians(degrees)
    turned = normal * math.cos(angle) + direction * math.sin(angle)
    return eqx.tree_at(lambda s: s.normal, samples, turned)


def specular_change(
    family, params, shading: TrackShading, weights, albedo, per_point: int, step: int = 1
):
    """The median relative change of the global lobes' prediction (summed over channels)
    when every normal is tilted 1 degree away from its half vector, over the observed
    tracks where those lobes are at least `SPECULAR_SHARE` of the model, and how many such
    observations there are. `weights` (K, 3) are the fitted global weights, `albedo`
    (P, 3) the points' (`fit_brdf_map`); on every `step`-th point only."""
    # The median on the host: XLA's CPU sort of 8 x 32k changes took 0.11 s, NumPy's
    # selection 2 ms.
    change = np.asarray(_changes(family, params, shading, weights, albedo, per_point, step))
    counted = np.isfinite(change)
    median = float(np.median(change[counted])) if counted.any() else float("nan")
    return median, int(counted.sum())


@persistent_jit
def _changes(family, params, shading: TrackShading, weights, albedo, per_point: int, step: int):
    """Every observation's relative change (M, P / step), NaN where it is not counted."""
    shading, albedo = shading.every(step), albedo[::step]
    turned = eqx.tree_at(lambda s: s.samples, shading, tilted(shading.samples, 1.0))

    def split(columns):
        specular = sum(c * jnp.sum(weights[k]) for k, c in enumerate(columns) if k != per_point)
        return specular, columns[per_point] * jnp.sum(albedo, axis=-1)

    specular, diffuse = split(track_columns(family, params, shading))
    tilted_specular, _ = split(track_columns(family, params, turned))
    counts = shading.observed & (specular > SPECULAR_SHARE * (specular + diffuse))
    counts = counts & (specular > 0)
    change = jnp.abs(tilted_specular - specular) / jnp.where(counts, specular, 1)
    return jnp.where(counts, change, jnp.nan)
