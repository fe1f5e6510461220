"""The geometry of a tracked point's candidate facets, shared by the facet protocol
(`ctjax.fitting._facets`) and the facets integrated out (`ctjax.fitting._facet_marginal`):
H of each of the point's views (`half_vectors`), the arc the scope's motion makes them
trace (`views_arc`), the candidate facets about them (`candidate_facets`), a point's lobe
columns about its reconstruction's normal and about any facet (`lobe_columns`), and the
samples regrouped per point (`grouped_per_point`)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp

from .._vector import Vec3
from ._map_least_squares import TrackSamples, diffuse_lobe

# The candidate facets: each view's H turned across the arc that the point's views' H
# trace, by each of these angles (radians). A scope's motion moves H along one arc; a
# facet off it is never any view's peak, and a lobe about the nearest H overshoots its
# views (so a weak lobe fitted best: on attached synthetic sparkles of roughness 0.06 and
# F_tilde 0.012, 12 frames, sigma 0.04-0.05 at the grid's bottom with F_tilde 0.002-0.003
# from the views' H alone; with these offsets and each view's own H 0.067 and 0.0084, with
# seven from -0.12 to 0.12 0.056 and 0.0044, on another seed 0.049 and 0.0039: the width
# within 20%, F_tilde a lower bound; `benchmarks/facet_truth.py`).
FACET_ACROSS_RAD = (-0.08, -0.04, 0.0, 0.04, 0.08)


def half_vectors(model, rotations, point, pixel, weight, frame):
    """H of each of one point's views (M, 3), world coordinates, at the view's (bilinear)
    point: the facet that would make that view the point's peak."""
    at = jnp.sum(point * weight[..., None], 0)  # (M, 3): each view's point, its camera frame
    to_eye = -at / jnp.linalg.norm(at, axis=-1, keepdims=True)
    uv = (jnp.sum(pixel[0] * weight, 0), jnp.sum(pixel[1] * weight, 0))

    def half(x, v, u, vv):
        light, _ = model.light.illuminate(Vec3.from_array(x), Vec3.from_array(v), (u, vv))
        h = light.to_array() + v
        return h / jnp.linalg.norm(h)

    return jnp.einsum("mij,mj->mi", rotations[frame], jax.vmap(half)(at, to_eye, *uv))


class CandidateSet(eqx.Module):
    """Which candidate facets a point gets: its views' H turned by each of `across` (rad,
    `candidate_facets`), each point's own (`shuffle` (P,) the identity) or another point's (a
    permutation: the control); `sets`: the
    choices made among them, each a mask over `across` (one pass for all)."""

    shuffle: jax.Array
    across: tuple = eqx.field(static=True)
    sets: tuple = eqx.field(static=True)


def views_arc(h, w):
    """The principal direction (3,) of the counted views' (`w` > 0) H (M, 3): the arc the
    scope's motion traces. By power iteration (no LAPACK), from the first to the last
    counted view's H (nudged off zero for a point seen once)."""
    counted = (w > 0)[:, None]
    mean = jnp.sum(jnp.where(counted, h, 0), 0) / jnp.maximum(jnp.sum(counted), 1)
    centred = jnp.where(counted, h - mean, 0)
    scatter = centred.T @ centred
    first, last = jnp.argmax(w > 0), h.shape[0] - 1 - jnp.argmax((w > 0)[::-1])
    arc = h[last] - h[first] + jnp.asarray([1e-6, 2e-6, 3e-6], h.dtype)
    for _ in range(8):
        arc = scatter @ arc + 1e-12 * arc
        arc = arc / jnp.linalg.norm(arc)
    return arc


def candidate_facets(h, w, across=FACET_ACROSS_RAD):
    """(D * M, 3) candidate facets of one point, world coordinates: each view's H (M, 3)
    turned by each angle of `across` about the arc of the counted views' H (`w` > 0,
    `views_arc`); candidate c is view c % M's."""
    normal = jnp.cross(h, views_arc(h, w))
    normal = normal / jnp.maximum(jnp.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    return jnp.concatenate([math.cos(d) * h + math.sin(d) * normal for d in across], 0)


def lobe_columns(model, turned, rotations, point, normal, pixel, weight, frame):
    """One tracked point's lobe columns (K, M) about its reconstruction's normals
    (`smooth`) and `about(facet)`: the same with the turned lobes (`turned`: "lobe" the
    lobes but the diffuse one, "diffuse" that one, "both" all) about one world direction."""
    diffuse = diffuse_lobe(model)
    lobes = len(model.brdf.lobes)
    others = [k for k in range(lobes) if k != diffuse]
    moved = {"lobe": others, "diffuse": [diffuse], "both": list(range(lobes))}[turned]
    corners, views = weight.shape

    def columns(normal_at):  # (4, M, 3) normals -> (K, M), bilinear over the corners
        def one(p, n, u, v):
            return model.columns(Vec3.from_array(p), Vec3.from_array(n), (u, v))

        c = jax.vmap(one)(
            point.reshape(-1, 3),
            normal_at.reshape(-1, 3),
            pixel[0].reshape(-1),
            pixel[1].reshape(-1),
        )
        return jnp.sum(c.reshape(corners, views, lobes) * weight[..., None], 0).T

    smooth = columns(normal)
    rotation = rotations[frame]  # (M, 3, 3): camera-to-world

    def about(facet):
        local = jnp.einsum("mji,j->mi", rotation, facet)
        c = columns(jnp.broadcast_to(local, point.shape))
        return smooth.at[jnp.array(moved)].set(c[jnp.array(moved)])

    return smooth, about


def grouped_per_point(model, samples: TrackSamples, judged, rotations, candidates: CandidateSet):
    """`samples` regrouped per tracked point (leading axis P), with each point's candidate
    facets (J, 3, `candidate_facets`) last."""
    views, points = samples.weight.shape
    shaped = lambda v: v.reshape(4, views, points)  # noqa: E731
    point = jnp.stack(
        [shaped(samples.point.x), shaped(samples.point.y), shaped(samples.point.z)], -1
    )
    normal = jnp.stack(
        [shaped(c) for c in (samples.normal.x, samples.normal.y, samples.normal.z)], -1
    )
    pixel = jnp.stack([shaped(samples.pixel[0]), shaped(samples.pixel[1])], 0)  # (2, 4, M, P)
    per_point = (
        jnp.moveaxis(point, 2, 0),
        jnp.moveaxis(normal, 2, 0),
        jnp.moveaxis(pixel, 3, 0),
        jnp.moveaxis(samples.corner_weight, 2, 0),
        jnp.moveaxis(samples.values, 2, 0),
        samples.weight.T,
        judged.T,
        jnp.maximum(samples.site.frame, 0).T,
    )
    h = jax.vmap(lambda *a: half_vectors(model, rotations, *a))(
        per_point[0], per_point[2], per_point[3], per_point[7]
    )
    facets = jax.vmap(lambda h, w: candidate_facets(h, w, candidates.across))(h, per_point[5])
    facets = facets[candidates.shuffle]  # the control: every point's candidates another's
    return (*per_point, facets)
