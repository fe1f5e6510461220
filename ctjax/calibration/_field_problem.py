"""The paper's per-pixel light problem (section 5, eq. 7-8), for one pixel; batches come
from `vmap`.

`theta`, `phi` are eq. (7)'s tilt and slant in the paper's frame, which is ctjax's camera
frame turned by 180 degrees about x (x right, y up, z towards the viewer):
`L = (sin phi cos theta, -sin phi sin theta, -cos phi)` in ctjax's frame. They are reported,
but the solvers work in tangent-plane coordinates around each pixel's start direction:
eq. (7) is singular at phi = 0, which is exactly the boundary value near the image centre.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._convert import cast_floating
from .._programs import persistent_jit
from .._typing import Array, Float
from .._vector import Vec3, tangent_direction
from ..lights import angles_from_direction
from ..lobes import BRDF
from ..solvers import ClosedFormLM, least_squares

# ctjax's camera frame -> the paper's (x right, y up, z towards the viewer).
_PAPER_FRAME = np.array([1.0, -1.0, -1.0])


def paper_angles(directions: Float[Array, "... 3"]) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (7)'s (theta, phi) of unit directions in ctjax's camera frame (radians).

    theta in [-pi, pi] (tilt), phi in [0, pi] (slant from the paper's z, the optical axis
    pointing back towards the camera; light in front of the surface: phi < pi / 2).
    """
    theta, phi = angles_from_direction(jnp.asarray(directions) * _PAPER_FRAME)
    return np.asarray(theta), np.asarray(phi)


def directions_from_paper_angles(theta, phi) -> np.ndarray:
    """Inverse of `paper_angles`: unit directions (..., 3) in ctjax's camera frame."""
    theta, phi = np.asarray(theta, float), np.asarray(phi, float)
    paper = np.stack([np.sin(phi) * np.cos(theta), np.sin(phi) * np.sin(theta), np.cos(phi)], -1)
    return paper * _PAPER_FRAME


class PixelProblem(eqx.Module):
    """One pixel's data over F frames (a batch of pixels under vmap): the unit view
    direction V (camera frame; the same in every frame, it depends on the pixel only), the
    unit normal and measured linear RGB in each frame, a weight per frame (1 where the
    pixel is in S-bar in that frame, else 0), the light's irradiance factor, the albedo of
    the surface point the pixel sees in each frame (with an albedo map; unused with one
    albedo), the start direction and the prior direction."""

    view: Vec3
    normal: Vec3  # components (F,)
    values: Float[Array, "F 3"]
    weight: Float[Array, " F"]
    irradiance: Float[Array, " F"]
    albedo: Float[Array, "F 3"]
    start: Vec3
    prior: Vec3


def _with_albedo(brdf: BRDF, per_point: int | None, albedo) -> BRDF:
    """`brdf` with lobe `per_point`'s weight replaced by `albedo` (None: as it is)."""
    if per_point is None:
        return brdf
    return brdf.with_weights(brdf.weights.at[per_point].set(albedo))


def pixel_residuals(
    y, problem: PixelProblem, brdf: BRDF, prior_scale, per_point: int | None = None
) -> Float[Array, " R"]:
    """Eq. (8)'s residuals of one pixel in 8-bit levels, every frame (F x 3), then the
    prior's three (`(L - L_prior) * prior_scale`, `prior_scale` = 1 / prior_deg in 1/rad).
    With `per_point` (the diffuse lobe's index; an albedo map), that lobe's weight in each
    frame is the albedo of the surface point seen there."""
    light = tangent_direction(problem.start, y)

    def one_frame(normal, values, weight, irradiance, albedo):
        local = _with_albedo(brdf, per_point, albedo)
        predicted = irradiance * local.radiance(normal, light, problem.view)
        return 255 * weight * (predicted - values)

    shading = jax.vmap(one_frame)(
        problem.normal, problem.values, problem.weight, problem.irradiance, problem.albedo
    )
    prior = (light - problem.prior).to_array() * prior_scale
    return jnp.concatenate([shading.reshape(-1), prior])


class PixelSolution(eqx.Module):
    """Per pixel: the unit light direction (camera frame), the solver's `Status` code, its
    number of steps and the data's RMSE (levels)."""

    direction: Float[Array, "P 3"]
    result: Array
    steps: Array
    rmse: Float[Array, " P"]


@persistent_jit
def solve_pixels(
    problems: PixelProblem,
    brdf: BRDF,
    prior_scale: float,
    solver: ClosedFormLM | optx.AbstractLeastSquaresSolver,
    max_steps: int = 24,
    per_point: int | None = None,
) -> PixelSolution:
    """Eq. (8) per pixel by `solver` (`ClosedFormLM`, or an optimistix solver such as
    `optx.LevenbergMarquardt` with at most `max_steps` steps), vmapped over the pixels of
    `problems` (a batch of `PixelProblem`s), from their start directions. With `per_point`
    (the diffuse lobe's index), that lobe's weight is each problem's per-frame albedo. Works
    in the dtype of `problems` (the BRDF is cast to it), float32 or float64."""
    brdf = cast_floating(brdf, problems.values.dtype)

    def residuals(y, problem, scale):
        return pixel_residuals(y, problem, brdf, scale, per_point)

    def one(problem):
        y0 = jnp.zeros(2, problem.values.dtype)
        y, status, steps = least_squares(
            lambda y: residuals(y, problem, prior_scale), solver, y0, max_steps
        )
        light = tangent_direction(problem.start, y)
        return light.to_array(), status, steps, _data_rmse(residuals(y, problem, 0.0), problem)

    direction, result, steps, rmse = jax.vmap(one)(problems)
    return PixelSolution(direction, result, steps, rmse)


def _data_rmse(residual, problem: PixelProblem):
    """One pixel's RMSE (levels) of its shading `residual`, over its observed values."""
    frames = problem.values.shape[0]
    count = 3 * jnp.maximum(jnp.sum(problem.weight), 1)
    return jnp.sqrt(jnp.sum(residual[: 3 * frames] ** 2) / count)
