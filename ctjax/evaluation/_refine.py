"""Per-pixel normal refinement (the paper's eq. 9): the normal that makes a reflectance model
reproduce the pixel's RGB, by Levenberg-Marquardt (optimistix) on autodiff Jacobians.

One pixel gives three equations (R, G, B) for the normal's two degrees of freedom; where the
specular term is negligible they are nearly collinear and a one-dimensional valley of normals
(a cone about the light) explains the pixel equally well. The solve starts from the given
normal (Tsai-Shah's, or the previous integrated surface's) and a small prior towards it
selects the point of the valley nearest to the start: the refinement changes the normal only
as much as the image requires.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .._programs import persistent_jit
from .._status import Status
from .._typing import Array, Float, Int
from .._vector import Vec3, tangent_direction

# Prior weight towards the starting normal, in 8-bit levels per radian of tilt.
PRIOR_LEVELS_PER_RADIAN = 2.0


class NormalRefinement(eqx.Module):
    """Refined unit normals (N, 3), each pixel's solver status (a `ctjax.Status` code:
    0 successful) and number of steps, and RMSE (8-bit levels) before and after."""

    normals: Float[Array, "N 3"]
    status: Int[Array, " N"]
    steps: Int[Array, " N"]
    rmse_before: Float[Array, " N"]
    rmse_after: Float[Array, " N"]


def refine_normal(
    model, point: Vec3, normal: Vec3, pixel, values, saturation, max_steps: int, prior: float
):
    """One pixel: the normal near `normal` whose predicted RGB best matches `values` (linear
    RGB), both clipped at each channel's `saturation` (1, the sensor's, or the camera's
    ceiling: a clipped value asks only for "at least this bright")."""
    measured = jnp.minimum(values, saturation)

    @jax.jit  # traced once for the solver and the two calls below (pjit's cache)
    def residuals(delta, _):
        predicted = model(point, tangent_direction(normal, delta), pixel)
        predicted = jnp.minimum(predicted, saturation)
        return jnp.concatenate([255.0 * (predicted - measured), prior * delta])

    start = jnp.zeros(2, values.dtype)
    solution = optx.least_squares(
        residuals,
        optx.LevenbergMarquardt(rtol=1e-4, atol=1e-4),
        start,
        max_steps=max_steps,
        throw=False,
    )
    refined = tangent_direction(normal, solution.value)
    before = residuals(start, None)[:3]
    after = residuals(solution.value, None)[:3]
    rms = lambda r: jnp.sqrt(jnp.mean(r * r))  # noqa: E731
    status = Status.of_optimistix(solution.result)
    return refined, status, solution.stats["num_steps"], rms(before), rms(after)


@persistent_jit
def refine_normals(
    model,
    points: Vec3,
    normals: Vec3,
    pixels,
    values: Float[Array, "N 3"],
    saturation: Float[Array, " 3"],
    *,
    max_steps: int = 20,
    prior: float = PRIOR_LEVELS_PER_RADIAN,
) -> NormalRefinement:
    """Refine N pixels' normals (eq. 9) under `model` (a `ShadingModel`: BRDF, light and
    effects), vmapped and jitted. `points` (mm) and `normals` are camera-frame `Vec3`s of
    (N,) arrays, `pixels` a (u, v) pair of (N,) arrays, `values` linear RGB (N, 3),
    `saturation` (3,) the level from which each channel is clipped (`Capture.saturation`)."""
    refined, status, steps, before, after = jax.vmap(
        lambda p, n, px, v: refine_normal(model, p, n, px, v, saturation, max_steps, prior)
    )(points, normals, pixels, values)
    return NormalRefinement(refined.to_array(), status, steps, before, after)
