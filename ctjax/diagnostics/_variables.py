"""Physical variables at each sample, where a missing effect shows up in the residuals."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._numerics import safe_normalize
from .._units import METRIC
from .._vector import Vec3

VARIABLES = {
    "n_dot_v": "N.V",
    "n_dot_l": "N.L",
    "angle_n_h_deg": "angle N-H (deg)",
    "angle_l_v_deg": "angle L-V (deg)",
    "light_distance_mm": "distance to the light (mm)",
    "radius_px": "distance from the image centre (px)",
    "predicted": "predicted intensity (mean RGB)",
}


def variable_label(name: str, length_unit: str = METRIC) -> str:
    """`VARIABLES[name]`, its length in `length_unit` (a capture reconstructed up to scale
    measures the distance to the light in median depths, not millimetres)."""
    label = VARIABLES[name]
    if name.endswith("_mm") and length_unit != METRIC:
        return label.replace("(mm)", "(median depths)")
    return label


def _angle(a: Vec3, b: Vec3):
    return jnp.degrees(jnp.arccos(jnp.clip(a @ b, -1.0, 1.0)))


def physical_variables(model, samples, camera) -> dict[str, jax.Array]:
    """Each variable of `VARIABLES` at every pixel sample, under `model`'s light."""
    return _variables(model, samples, camera)


@eqx.filter_jit  # one program per model structure and sample count, not one per call
def _variables(model, samples, camera) -> dict[str, jax.Array]:
    def one(sample):
        view = safe_normalize(-sample.point)
        light, _ = model.light.illuminate(sample.point, view, sample.pixel)
        half = safe_normalize(light + view)
        position = getattr(model.light, "position_mm", jnp.zeros(3))
        to_light = Vec3.from_array(position) - sample.point
        u, v = sample.pixel
        return {
            "n_dot_v": sample.normal @ view,
            "n_dot_l": sample.normal @ light,
            "angle_n_h_deg": _angle(sample.normal, half),
            "angle_l_v_deg": _angle(light, view),
            "light_distance_mm": jnp.sqrt(to_light @ to_light),
            "radius_px": jnp.hypot(u - camera.cx, v - camera.cy),
            "predicted": jnp.mean(model(sample.point, sample.normal, sample.pixel)),
        }

    return jax.vmap(one)(samples)


def binned(x, residual, bins: int = 16):
    """Mean residual per quantile bin of `x`: (bin centres, mean residual (bins, C), counts)."""
    import numpy as np

    x = np.asarray(x)
    residual = np.asarray(residual)
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    index = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    centres, means, counts = [], [], []
    for b in range(len(edges) - 1):
        mask = index == b
        if mask.sum() == 0:
            continue
        centres.append(float(np.mean(x[mask])))
        means.append(residual[mask].mean(axis=0))
        counts.append(int(mask.sum()))
    return np.array(centres), np.array(means), np.array(counts)
