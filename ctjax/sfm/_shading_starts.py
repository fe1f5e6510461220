"""Where the shading refinement's Levenberg-Marquardt starts (`ctjax.sfm._shading`): sigma
from the branch and bound's and `SIGMA_STARTS`, the light from its own position and
`offset_starts`, and which of those starts the light-only descents take."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

# Roughnesses the refinement may start from, beside the BnB's (which assumes the light at
# the camera: under a light off the lens it sat at 0.73 where the truth is 0.2, and LM went
# on from there to 1.3 with the shape bent to fit; `ctjax synth --stereo 5` 320x256 x 8 seed 2).
SIGMA_STARTS = (0.05, 0.1, 0.15, 0.2, 0.3, 0.45, 0.7)


def light_starts(light, length_unit: str, median_depth: float) -> list:
    """The light itself and, for a light with a position (`position_field`: a
    `PointLight`'s, a `LensPlaneLight`'s offset in the lens plane), that position moved by
    each of `offset_starts` (the cost is not convex in the position)."""
    from ..lights._point import offset_starts

    field = getattr(type(light), "position_field", None)
    if field is None:
        return [light]
    position = getattr(light, field)

    def moved(offset):
        step = jnp.asarray(offset[: position.shape[0]], float)
        return eqx.tree_at(lambda l: getattr(l, field), light, position + step)

    return [light] + [moved(o) for o in offset_starts(length_unit, median_depth)]


def shading_starts(points, sigma: float, residual, length_unit: str, median_depth: float):
    """(cost, theta) from a flat correction and each (sigma, light) start, lowest cost
    first: sigma from the BnB's and `SIGMA_STARTS`, the light from `light_starts`. One
    residual each (no Jacobian): a few seconds."""
    problem = points.problem
    starts = []
    for light in light_starts(problem.light, length_unit, median_depth):
        for roughness in (sigma, *SIGMA_STARTS):
            g = np.concatenate([[roughness], problem.free.vector(light)])
            theta = jnp.asarray(np.concatenate([np.zeros(points.spline.size), g]))
            r = np.asarray(residual(problem, theta))
            starts.append((float(r @ r), theta))
    return sorted(starts, key=lambda start: start[0])


# With a light to fit, LM first moves sigma and the light alone (the shape held) from this
# many of the best starts, at most `GLOBAL_ITERATIONS` steps each, then everything from
# the best: fitted jointly from the start, the surface bent to absorb the light's error
# (on the true shape of `ctjax synth --stereo 5` 192x160 x 3, light at (4, -3, 0) mm:
# sigma 0.83 where the truth is 0.2, the position 0.5-0.8 mm off).
LIGHT_STARTS = 2
GLOBAL_ITERATIONS = 8
# ... starts whose roughnesses differ by this factor at least: a broad lobe with the light
# misplaced and a sharp one are two basins, and the best starts can all lie in one. Seed 1
# of `ctjax synth --stereo 5 --light-offset 4 -3 0 --inverse-square` 320x256 x 8: the two best
# starts were sigma 0.7 and 0.83 (the BnB's) with one light; both ran to sigma 1.15 (cost
# 0.508) and the joint fit to 1.13 with the light 1.03 mm off, where the best start of
# sigma 0.2 ran to 0.17 (cost 0.504), the joint fit to 0.167 and 0.62 mm.
DISTINCT_SIGMA = 2.0


def distinct_starts(starts: list, size: int, count: int) -> list:
    """The `count` best of `starts` (cost, theta; lowest cost first) whose roughnesses
    (theta[size]) are each at least `DISTINCT_SIGMA` times apart from the better ones'."""
    chosen, sigmas = [], []
    for cost, theta in starts:
        sigma = float(theta[size])
        if all(max(sigma / s, s / sigma) >= DISTINCT_SIGMA for s in sigmas):
            chosen.append((cost, theta))
            sigmas.append(sigma)
        if len(chosen) == count:
            break
    return chosen
