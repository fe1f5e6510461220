"""One normal per surface point: the frames' own normals of a tracked point made one.

On real video each frame's depth and normals are its own (a surface fitted per frame, or
each frame's own stereo pair), so the same surface point's normal differs from frame to
frame, which the shading of a rigid surface under a light that moves with the camera
cannot do. `one_normal_per_point` turns every view's normals to the point's mean (the
observations do so for every track they follow); `frames_disagree_deg` says by how much
the frames disagreed.
"""

import dataclasses
import math

import numpy as np

from ._geometry import cross
from ._tracks import Tracks


def views_and_mean(tracks: Tracks, capture):
    """Each view's unit normal (P, M, 3; bilinear over its corners, in its frame), its
    frame's rotation (P, M, 3, 3; camera-to-world), whether it counts (P, M) and each
    point's mean normal in world coordinates (P, 3; NaN where no view counts)."""
    own = np.einsum("pmc,pmcd->pmd", tracks.corner_weight, tracks.corner_normal)
    rotation = np.stack([np.asarray(f.pose, float)[:3, :3] for f in capture.frames])
    seen = tracks.observed & (tracks.frame >= 0)
    turn = rotation[np.where(seen, tracks.frame, 0)]
    with np.errstate(invalid="ignore"):  # a corner without a normal: NaN, not seen below
        own /= np.linalg.norm(own, axis=-1, keepdims=True)
    world = np.einsum("pmij,pmj->pmi", turn, own)
    seen &= np.all(np.isfinite(world), axis=-1)
    mean = np.where(seen[..., None], world, 0).sum(axis=1)
    norm = np.linalg.norm(mean, axis=-1, keepdims=True)
    mean = np.where(norm > 0, mean / np.where(norm > 0, norm, 1), np.nan)
    return own, turn, seen, mean


def point_normals(tracks: Tracks, capture) -> np.ndarray:
    """Each tracked point's normal in world coordinates (P, 3): the mean of its views'
    (`one_normal_per_point`); NaN for a point no view of which counts."""
    return views_and_mean(tracks, capture)[3]


def frames_disagree_deg(tracks: Tracks, capture) -> float:
    """How much the frames' own normals of the same surface points disagree: the RMS angle
    (degrees) between each view's normal in its frame's normal map (bilinear over its
    corners) and the point's one normal (`point_normals`), over the observed views of points
    seen twice or more; NaN where there are none. 0 for one surface seen by every frame;
    5.9 on a real da Vinci clip with each frame's depth from its own pair, 10.3 on the shared
    sinus's per-frame SfM surfaces."""
    mean = point_normals(tracks, capture)
    seen = tracks.observed & (tracks.frame >= 0) & (tracks.views[:, None] > 1)
    angles = []
    for index in np.unique(tracks.frame[seen]):
        frame = capture.frames[int(index)]
        at = seen & (tracks.frame == index)
        pixel = np.rint(tracks.corner_pixel[at]).astype(int)  # (V, 4, 2) pixel centres
        u = np.clip(pixel[..., 0], 0, frame.normals.shape[1] - 1)
        v = np.clip(pixel[..., 1], 0, frame.normals.shape[0] - 1)
        own = np.einsum("vc,vcd->vd", tracks.corner_weight[at], frame.normals[v, u])
        world = own @ np.asarray(frame.pose, float)[:3, :3].T
        with np.errstate(invalid="ignore"):
            world /= np.linalg.norm(world, axis=-1, keepdims=True)
        cosine = np.clip(np.sum(world * mean[np.nonzero(at)[0]], axis=-1), -1, 1)
        angles.append(np.degrees(np.arccos(cosine[np.isfinite(cosine)])))
    angles = np.concatenate(angles) if angles else np.zeros(0)
    return float(np.sqrt(np.mean(angles**2))) if len(angles) else math.nan


def one_normal_per_point(tracks: Tracks, capture) -> Tracks:
    """`tracks` with each surface point's normal made one: every observation's corners
    turned by the least rotation that takes the observation's normal (bilinear over its
    corners) to the point's, the mean of its observations' normals in world coordinates
    (by the frames' poses). The corners keep their spread about it (a sharp lobe's
    bilinear shading depends on it), each frame's own error is removed.

    The frames' depth and normals are each frame's own (a surface fitted per frame, or each
    frame's own stereo pair): on real video the same point's normal differs from frame to
    frame (5.9 degrees RMS on the SurgT da Vinci clip, 10.3 on the shared sinus), which the
    shading of a rigid surface under a light that moves with the camera cannot do. Left per
    frame, that noise biases the fit as a broad trend: on a synthetic capture whose normals
    were tilted 5 degrees RMS per frame, sigma went to the top of its range (0.9998 for
    0.2), and Oren-Nayar's roughness to 0.44 (1.52 at 10 degrees) where the truth is
    Lambertian; with one normal per point, sigma 0.222 and the roughness 0.03. Views that
    are not observed (clipped) keep their frame's normals."""
    own, turn, seen, mean = views_and_mean(tracks, capture)
    target = np.einsum("pmji,pj->pmi", turn, mean)  # in each frame: the transpose
    # The least rotation taking u to v: x + w x x + w x (w x x) / (1 + u.v), w = u x v.
    w = cross(own, target)[:, :, None, :]
    c = np.sum(own * target, axis=-1)[:, :, None, None]
    x = tracks.corner_normal
    # x + w x x + w x (w x x) / (1 + c), w x x once and the rest in place (the same
    # operations in the same order: the same bits, in less memory).
    w_x = cross(w, x)
    turned = x + w_x
    bend = cross(w, w_x)
    del w_x
    bend /= np.maximum(1 + c, 1e-6)
    turned += bend
    del bend
    keep = (seen[..., None, None] & (c > 0)) & np.all(np.isfinite(turned), -1, keepdims=True)
    normals = np.where(keep, turned, x).astype(x.dtype, copy=False)
    return dataclasses.replace(tracks, corner_normal=normals)
