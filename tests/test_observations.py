"""A capture as observations: the samples every estimator consumes, built in one place."""

import numpy as np
import pytest

from ctjax import CtjaxError, Observations
from ctjax.io import load_capture
from ctjax.synth import SynthOptions, synthesize


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("obs") / "c"
    return load_capture(synthesize(root, SynthOptions(width=48, height=40, frames=3, seed=2)))


def test_pixels_are_the_frames_own_values_in_any_frame_order(capture):
    obs = Observations.of(capture)
    assert Observations.of(obs) is obs  # built once, passed down as is
    for frames in ([0, 2], [2, 0]):
        samples = obs.pixels(frames, max_samples=500, seed=1)
        frame, row, col = (np.asarray(a) for a in (samples.frame, samples.row, samples.col))
        assert set(frame) == set(frames) and len(frame) == 500
        for i in frames:
            pick = frame == i
            image, depth = capture.frames[i].image, capture.frames[i].depth
            np.testing.assert_array_equal(
                np.asarray(samples.values)[pick], image[row[pick], col[pick]]
            )
            np.testing.assert_allclose(
                np.asarray(samples.point.z)[pick], depth[row[pick], col[pick]]
            )
            assert obs.usable[i][row[pick], col[pick]].all()


def test_ring_and_view_directions(capture):
    obs = Observations.of(capture)
    ring = obs.ring()
    assert len(ring) == sum(int(s.ring.sum()) for s in obs.sets) > 0
    np.testing.assert_allclose(np.linalg.norm(obs.view, axis=-1), 1)
    assert np.all(obs.view[..., 2] < 0)  # towards the camera
    assert 40 < obs.median_depth_mm() < 120


def test_no_usable_pixel_is_one_clear_error(capture):
    obs = Observations.of(capture)
    obs.usable = [np.zeros_like(u) for u in obs.usable]
    with pytest.raises(CtjaxError, match="no usable pixel"):
        obs.pixels([0])


def test_tracked_points_are_spread_evenly_over_the_frame():
    # The anchors kept are evenly spaced along the Z-order curve: on a 64 x 64 frame, 256
    # of its 4096 pixels are one in each aligned 4 x 4 block, whatever the random offset.
    from ctjax.observations import _evenly

    everywhere = np.ones((64, 64), bool)
    for seed in range(3):
        kept = _evenly(everywhere, 256, np.random.default_rng(seed))
        assert len(kept) == 256 and np.all(np.diff(kept) > 0)
        rows, cols = np.divmod(kept, 64)
        assert sorted((rows // 4) * 16 + cols // 4) == list(range(256))
    # Any mask, any count: distinct pixels of the mask, sorted; all of them at most.
    mask = np.random.default_rng(0).random((64, 64)) < 0.3
    kept = _evenly(mask, 100, np.random.default_rng(1))
    assert len(kept) == 100 and np.all(np.diff(kept) > 0) and np.all(mask.reshape(-1)[kept])
    assert np.array_equal(_evenly(mask, 10**6, np.random.default_rng(1)), np.flatnonzero(mask))
    assert len(_evenly(mask, 0, np.random.default_rng(0))) == 0


def test_tracks_are_built_once_per_request(capture):
    """The held-out split, the noise floor and the fits of one command ask the same
    observations for the same tracks: followed once, then handed out as built."""
    obs = Observations.of(capture)
    first = obs.tracks(max_points=200, frames=[0, 1])
    assert obs.tracks(max_points=200, frames=(0, 1)) is first
    assert obs.tracks(max_points=200, frames=[0, 1], seed=1) is not first
    other = obs.tracks(max_points=200)
    assert other is not first and len(other.observed[0]) == 3
    # New observations of the same capture start afresh.
    assert Observations(capture).tracks(max_points=200, frames=[0, 1]) is not first


def _world_normals(capture, tracks):
    """Each observation's normal (bilinear over its corners) in world coordinates."""
    normal = np.einsum("pmc,pmcd->pmd", tracks.corner_weight, tracks.corner_normal)
    with np.errstate(invalid="ignore"):  # views that are not observed: NaN, not compared
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    rotation = np.stack([f.pose[:3, :3] for f in capture.frames])
    return np.einsum("pmij,pmj->pmi", rotation[np.maximum(tracks.frame, 0)], normal)


def test_a_surface_point_has_one_normal_in_every_frame(tmp_path):
    """Each frame's normals are its own (a surface per frame, a stereo pair per frame): a
    point's normal differs between frames on real video, which a rigid surface's cannot.
    The tracks turn each view to the point's mean normal, keeping the corners' spread."""
    import dataclasses

    root = synthesize(tmp_path / "c", SynthOptions(width=96, height=80, frames=3, seed=2))
    exact = load_capture(root)
    rng = np.random.default_rng(0)
    frames = []
    for frame in exact.frames:  # each frame's normals tilted its own way, 4 degrees
        tilt = rng.normal(size=3) * np.tan(np.radians(4)) / np.sqrt(2)
        normals = frame.normals + tilt
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
        frames.append(dataclasses.replace(frame, normals=normals.astype(frame.normals.dtype)))
    tilted = dataclasses.replace(exact, frames=frames)
    # How much the frames disagree, measured against each frame's own normal map.
    from ctjax._point_normals import frames_disagree_deg

    assert frames_disagree_deg(Observations.of(exact).tracks(), exact) < 0.05
    assert 1.5 < frames_disagree_deg(Observations.of(tilted).tracks(), tilted) < 5
    for capture in (exact, tilted):
        tracks = Observations.of(capture).tracks()
        tracks = tracks.select(tracks.views > 1)
        world = _world_normals(capture, tracks)
        seen = tracks.observed
        mean = np.where(seen[..., None], world, 0).sum(1)
        mean /= np.linalg.norm(mean, axis=-1, keepdims=True)
        spread = np.degrees(np.arccos(np.clip(np.sum(world * mean[:, None], -1), -1, 1)))
        assert np.max(spread[seen]) < 1e-3
    # Once one, they stay: a second pass leaves every corner where it is.
    from ctjax._point_normals import one_normal_per_point

    tracks = Observations.of(exact).tracks()
    again = one_normal_per_point(tracks, exact)
    seen = tracks.observed
    np.testing.assert_allclose(again.corner_normal[seen], tracks.corner_normal[seen], atol=2e-3)


def test_the_clipped_share_is_given_where_a_tenth_or_more_is_clipped(capture):
    """`clipped_note`, which the errors for too few usable views end with: the share of the
    pixels with geometry that are clipped or in S, mean and per frame, from a tenth up."""
    import dataclasses

    obs = Observations.of(capture)
    assert obs.clipped_note() == ""  # the synthetic highlights: under a tenth
    clipped = Observations(capture, obs.masks)
    sets = []
    for k, (frame, s) in enumerate(zip(capture.frames, obs.sets, strict=True)):
        rows = np.nonzero(frame.geometry_mask.any(1))[0]
        band = np.zeros_like(s.clipped)
        band[rows[: int(len(rows) * (0.2 + 0.3 * k))]] = True  # 20%, 50%, 80% of the rows
        sets.append(dataclasses.replace(s, clipped=band & frame.geometry_mask[..., None]))
    clipped.__dict__["sets"] = sets  # the cached sets, as a clipped exposure leaves them
    shares = [
        float(np.mean((s.saturated | s.specular)[f.geometry_mask]))
        for f, s in zip(capture.frames, sets, strict=True)
    ]
    note = clipped.clipped_note()
    assert note.startswith(f"; {np.mean(shares):.0%} of the pixels with geometry are clipped")
    assert f"({min(shares):.0%}-{max(shares):.0%} per frame)" in note
