"""The held-out protocol, written once: split the frames, fit on the calibration frames,
judge on the held-out frames against the noise floor.

Calibration, evaluation and diagnostics all use it; it sits below them (it needs only the
capture, the pixel samples and the model), so none of them imports another for it.
"""

import dataclasses
import math
from collections.abc import Sequence

import equinox as eqx
import jax
import numpy as np

from ._convert import on_device
from ._errors import CtjaxError
from ._frame_consistency import BRIGHTNESS_OFF_LOG as BRIGHTNESS_OFF_LOG
from ._frame_consistency import NOT_PREDICTED_FACTOR as NOT_PREDICTED_FACTOR
from ._frame_consistency import frame_consistency as frame_consistency
from ._frame_consistency import frame_gains
from ._frame_consistency import frames_not_predicted as frames_not_predicted
from ._noise_floor import noise_floor_levels as noise_floor_levels
from ._noise_floor import noise_floor_map_levels as noise_floor_map_levels
from ._paired import SampleErrors
from ._result import Estimate
from ._right_views import require_stereo, with_right_views
from .fitting._facet_lobe import facet_lobe
from .fitting._facet_marginal import facet_marginal
from .fitting._fit import fit_model, pixel_predict, rmse_levels, squared_errors
from .fitting._map_least_squares import (
    MAP_LM_DTYPE,
    TrackSamples,
    fit_model_map,
    heldout_map_errors,
    heldout_map_residuals,
    heldout_map_rmse,
    in_radiance,
)
from .fitting._marginal_width import at_the_marginal_width
from .fitting._parameters import free_parameters
from .io import Capture
from .lights import LightField
from .observations import Observations, PixelSamples

# Among models within this fraction of the lowest held-out RMSE, the simplest is kept: a
# component the data do not show fits to ~nothing and would otherwise win on noise.
SIMPLEST_WITHIN = 0.01


def split_frames(
    count: int, calibration: int | None = None, *, source=None
) -> tuple[list[int], list[int]]:
    """The first frames calibrate, the rest are held out (default: 60% / 40%).

    `source` (the capture's folder) names the capture in the errors.
    """
    where = f"{source}: " if source is not None else ""
    if count < 2:
        raise CtjaxError(
            f"{where}needs at least 2 frames (calibration and held-out), the capture has {count}"
        )
    if calibration is None:
        calibration = min(count - 1, max(1, math.ceil(0.6 * count)))
    if not 1 <= calibration < count:
        raise CtjaxError(
            f"{where}--calib (calibration frames) must be between 1 and {count - 1} for "
            f"{count} frames, got {calibration}"
        )
    return list(range(calibration)), list(range(calibration, count))


# LM steps for a model's per-frame parameters on the held-out frames (one exposure each:
# a handful of steps converge), and the most tracked points (pixels: 4x) they are fitted
# on: a value per frame needs few, and every candidate of a diagnosis pays for the fit.
_PER_FRAME_STEPS = 30
_PER_FRAME_POINTS = 2048


def _per_frame_fitted(model, fit_held):
    """`model` with its per-frame parameters (`PER_FRAME`: an exposure per frame) fitted on
    the held-out samples by `fit_held(model, freeze)`, everything else as fitted on the
    calibration frames: a frame's exposure is that frame's nuisance, as a point's albedo
    is the point's, and a model fitted on other frames cannot know it. A handful of values
    per frame against thousands of observations: the held-out error barely sees them.
    `model` itself where it has none."""
    parameters = free_parameters(model)
    per_frame = [p for p in parameters if p.per_frame]
    if not per_frame:
        return model
    fitted = fit_held(model, [p.name for p in parameters if not p.per_frame]).model
    return eqx.tree_at(
        lambda m: [p.get(m) for p in per_frame], model, [p.get(fitted) for p in per_frame]
    )


def median_depth_mm(capture) -> float:
    """Median depth (mm) of every frame's usable pixels: the working distance, where a
    falloff's reference is put (so that rho_tilde and F_tilde read as there)."""
    return Observations.of(capture).median_depth_mm()


@dataclasses.dataclass
class HeldOut:
    """A capture split into calibration and held-out frames, with the pixel samples of each
    (built once, shared by every model compared on them).

    `train`: at most `max_samples` usable pixels of the calibration frames (what models are
    fitted on); `test`: at most `heldout_samples` of the held-out frames (what they are
    judged on). Random subsets, deterministic for a seed.
    """

    capture: Observations
    calibration: list[int]
    heldout: list[int]
    train: PixelSamples
    test: PixelSamples

    @classmethod
    def split(
        cls,
        capture: "Capture | Observations",
        calibration: int | None = None,
        *,
        max_samples: int | None = 12_000,
        heldout_samples: int | None = 40_000,
        seed: int = 0,
    ) -> "HeldOut":
        """Split `capture` (`calibration`: the number of calibration frames, default 60%)."""
        obs = Observations.of(capture)
        calib, heldout = split_frames(len(obs), calibration, source=obs.root)
        train = obs.pixels(calib, max_samples=max_samples, seed=seed)
        test = obs.pixels(heldout, max_samples=heldout_samples, seed=seed + 1)
        return cls(obs, calib, heldout, train, test)

    @property
    def frames(self) -> dict[str, list[int]]:
        return {"calibration": self.calibration, "heldout": self.heldout}

    def heldout_rmse(self, model) -> float:
        """RMSE (8-bit levels) of `model` on the held-out samples (its per-frame parameters,
        if any, fitted there: `with_heldout_frames`)."""
        return float(rmse_levels(self.with_heldout_frames(model), self.test, pixel_predict))

    def with_heldout_frames(self, model):
        """`model` with its per-frame parameters fitted on (a subset of) the held-out
        samples."""
        # Every k-th sample: they are sorted by frame, and every frame needs its share.
        step = max(1, len(self.test) // (4 * _PER_FRAME_POINTS))

        def fitted(m, freeze):  # (only for a model with per-frame parameters)
            # Strided on the host: an eager slice compiles a program per shape.
            subset = jax.tree_util.tree_map(lambda a: on_device(np.asarray(a)[::step]), self.test)
            return fit_model(m, subset, pixel_predict, freeze=freeze, max_steps=_PER_FRAME_STEPS)

        return _per_frame_fitted(model, fitted)

    def rmse(self, model) -> dict[str, float]:
        """RMSE (8-bit levels) of `model` on the calibration and the held-out samples."""
        return {
            "calibration": float(rmse_levels(model, self.train, pixel_predict)),
            "heldout": self.heldout_rmse(model),
        }

    def heldout_errors(self, model) -> SampleErrors:
        """Each held-out sample's error under `model` as `judge` left it (its per-frame
        parameters fitted there): for comparing two judged models (`ctjax._paired`)."""
        test = self.test
        count = np.full(len(test), test.values.shape[-1], float)
        frame, row, col = (np.asarray(a) for a in (test.frame, test.row, test.col))
        return SampleErrors(squared_errors(model, test, pixel_predict), count, frame, row, col)

    def noise_floor(self, model) -> float:
        """The noise floor (8-bit levels) of the held-out frames' residuals under `model`."""
        return noise_floor_levels(self.capture, self.heldout, model)

    def judge(self, fit: Estimate, *, noise_floor: bool = True) -> Estimate:
        """`fit` (fitted on `train`) with its held-out RMSE, noise floor and frames (its
        per-frame parameters, if any, fitted on the held-out frames)."""
        model = self.with_heldout_frames(fit.model)
        rmse = {
            "calibration": fit.rmse.get("calibration", math.nan),
            "heldout": float(rmse_levels(model, self.test, pixel_predict)),
        }
        return dataclasses.replace(
            fit,
            model=model,
            rmse=rmse,
            noise_floor=self.noise_floor(model) if noise_floor else fit.noise_floor,
            frames=self.frames,
        )


@dataclasses.dataclass
class HeldOutTracks:
    """The held-out protocol with an albedo map: surface points of the calibration frames
    followed within the calibration frames (`train`, what models are fitted on) and points
    of the held-out frames followed into every frame (`test`). A model is judged on the
    held-out frames' views of `test` (`judged`): each predicted with the model fixed and the
    point's albedo (a nuisance) fitted to its other views (`heldout_map_rmse`), so what is
    judged is how the model explains the change of a point's shading from view to view,
    never the texture, and no view is fitted to itself."""

    capture: Observations
    calibration: list[int]
    heldout: list[int]
    train: TrackSamples
    test: TrackSamples
    judged: np.ndarray
    # A subset of `test`'s points, for the models' per-frame parameters (`PER_FRAME`).
    nuisance: TrackSamples | None = None

    @classmethod
    def split(
        cls,
        capture: "Capture | Observations",
        calibration: int | None = None,
        *,
        max_points: int | None = 12_000,
        heldout_points: int | None = 20_000,
        seed: int = 0,
        right_views: bool = False,
    ) -> "HeldOutTracks":
        """Split `capture` (`calibration`: the number of calibration frames, default 60%);
        at most `max_points` and `heldout_points` tracked points (anchored near S and as
        many elsewhere, see `Observations.tracks`). `right_views`: `train` also holds the
        calibration frames' right views of a stereo capture (`ctjax._right_views`)."""
        obs = Observations.of(capture)
        calib, heldout = split_frames(len(obs), calibration, source=obs.root)
        if len(calib) < 2:
            remedy = (
                f"--calib between 2 and {len(obs) - 1}"
                if len(obs) >= 3
                else f"3 frames or more (the capture has {len(obs)}: 1 to calibrate, 1 held out)"
            )
            raise CtjaxError(
                f"{obs.root}: a fit with an albedo map needs at least 2 calibration frames (a "
                f"point's albedo is one unknown for its views); got {len(calib)}: give "
                f"{remedy}, or --albedo uniform (the paper's one albedo)"
            )
        train = obs.tracks(frames=calib, max_points=max_points, seed=seed)
        if right_views:
            train, _ = with_right_views(obs.capture, train, calib)
        test = obs.tracks(max_points=heldout_points, seed=seed + 1, anchor_frames=heldout)
        samples = TrackSamples.of(test)  # padded: the rows past the tracks are not judged
        judged = np.zeros(samples.weight.shape, bool)  # (M, P) as the samples
        judged[:, : len(test)] = (np.isin(test.frame, heldout) & test.observed).T
        rng = np.random.default_rng(seed + 2)
        few = np.sort(rng.permutation(len(test))[:_PER_FRAME_POINTS])
        nuisance = TrackSamples.of(test.select(few))
        return cls(obs, calib, heldout, TrackSamples.of(train), samples, judged, nuisance)

    @property
    def frames(self) -> dict[str, list[int]]:
        return {"calibration": self.calibration, "heldout": self.heldout}

    def facet_lobe(self, light, **options):
        """The lobe about every tracked point's own facet under `light`
        (`ctjax.fitting.facet_lobe`): chosen on `train`, judged on the held-out views."""
        frames = self.capture.capture.frames
        rotations = np.stack([np.asarray(f.pose, float)[:3, :3] for f in frames])
        return facet_lobe(self.train, self.test, self.judged, rotations, light, **options)

    def facet_marginal(self, light, **options):
        """The lobe about every tracked point's own facet under `light`, the facets
        integrated out (`ctjax.fitting.facet_marginal`), on `train`."""
        frames = self.capture.capture.frames
        rotations = np.stack([np.asarray(f.pose, float)[:3, :3] for f in frames])
        return facet_marginal(self.train, rotations, light, **options)

    def facet_blocks(
        self, light, *, lobe: bool = True, marginal: bool = False, unsteady=()
    ) -> dict:
        """The facet estimators' JSON under `light`, by the name a command writes each
        under: `facets` (`facet_lobe`, judged again without the `unsteady` frames, see
        there), `facet_marginal`, and with both `facets_at_the_marginal_width`
        (`facet_lobe_at_the_marginal_width`)."""
        blocks = {}
        if lobe:
            blocks["facets"] = self.facet_lobe(light, unsteady=unsteady).to_json()
        if marginal:
            blocks["facet_marginal"] = self.facet_marginal(light).to_json()
        if lobe and marginal:
            blocks["facets_at_the_marginal_width"] = self.facet_lobe_at_the_marginal_width(
                light, blocks["facet_marginal"], unsteady
            )
        return blocks

    def model_facet_blocks(self, model, *, unsteady=None, **which) -> dict:
        """`facet_blocks` under `model`'s light; a model with image effects on the views
        with its effects undone (`in_radiance`), their names in the facets' JSON
        (`effects_undone`). `which`: `facet_blocks`' `lobe` and `marginal`; `unsteady`:
        the held-out frames judged again without (default: those whose brightness `model`
        does not follow, `frames_off_in_brightness`)."""
        if unsteady is None and which.get("lobe", True):
            unsteady = self.frames_off_in_brightness(model)
        effects = [type(effect).__name__ for effect in getattr(model, "effects", ())]
        tracks, model = self.in_radiance(model)
        which["unsteady"] = unsteady or ()
        blocks = tracks.facet_blocks(model.light, **which)
        for block in blocks.values() if effects else ():
            block["effects_undone"] = effects
        return blocks

    def facet_lobe_at_the_marginal_width(self, light, marginal: dict, unsteady=()) -> dict:
        """The facet lobe under `light` with sigma held at the marginal's
        (`FacetMarginal.to_json()`), its F_tilde chosen and judged as `facet_lobe`'s (the
        `unsteady` frames too; `ctjax.fitting.at_the_marginal_width`), as JSON."""
        lobe = self.facet_lobe(light, sigmas=(float(marginal["sigma"]),), unsteady=unsteady)
        return at_the_marginal_width(lobe, marginal)

    def in_radiance(self, model) -> tuple["HeldOutTracks", object]:
        """These tracks with `model`'s image effects undone on every observation (its
        per-frame parameters fitted on the held-out frames first, `with_heldout_frames`;
        each weight times the effects' squared slope: `ctjax.fitting.in_radiance`) and
        `model` without them: for estimators of a model without image effects (the
        facets). Without effects: these tracks and `model`."""
        if not tuple(getattr(model, "effects", ())):
            return self, model
        model = self.with_heldout_frames(model)
        undone = dataclasses.replace(
            self,
            train=in_radiance(model, self.train),
            test=in_radiance(model, self.test),
            nuisance=None,
        )
        return undone, eqx.tree_at(lambda m: m.effects, model, ())

    def heldout_rmse(self, model) -> float:
        """RMSE (8-bit levels) of `model` on the held-out views (see the class doc; its
        per-frame parameters, if any, fitted there: `with_heldout_frames`)."""
        return heldout_map_rmse(self.with_heldout_frames(model), self.test, self.judged)

    def with_heldout_frames(self, model):
        """`model` with its per-frame parameters fitted on (a subset of) the held-out
        tracks (every point's albedo eliminated as in the fit)."""
        return _per_frame_fitted(
            model,
            lambda m, freeze: fit_model_map(
                m,
                self.test if self.nuisance is None else self.nuisance,
                freeze=freeze,
                max_steps=_PER_FRAME_STEPS,
                standard_errors=False,
                dtype=MAP_LM_DTYPE,
            ),
        )

    def rmse(self, model) -> dict[str, float]:
        """RMSE (8-bit levels) of a model fitted elsewhere: every view of `train` and the
        held-out views of `test`, each predicted from the albedo of the point's other views."""
        return {
            "calibration": heldout_map_rmse(model, self.train),
            "heldout": self.heldout_rmse(model),
        }

    def frame_rmse(self, model) -> dict[int, float]:
        """Each frame's RMSE (8-bit levels) as `rmse` counts it, by frame index: a
        calibration frame's over its views in `train`, a held-out frame's over its judged
        views in `test` (NaN for a frame with none). A frame far above the others is one
        its neighbours do not predict under the model (`frames_not_predicted`)."""
        out = {}
        for samples, judged, tested in (
            (self.train, None, model),
            (self.test, self.judged, self.with_heldout_frames(model)),
        ):
            residual, weight = heldout_map_residuals(tested, samples, judged)
            frame = np.asarray(samples.site.frame)
            squared = np.sum(residual * residual, axis=0) * weight
            for f in self.calibration if judged is None else self.heldout:
                here = (frame == f) & (weight > 0)
                total = float(np.sum(weight[here])) * residual.shape[0]
                out[f] = math.sqrt(float(np.sum(squared[here])) / total) if total else math.nan
        return out

    def frames_off_in_brightness(self, model) -> list[int]:
        """The held-out frames (indices) whose brightness `model` does not follow: measured
        over predicted off by more than `BRIGHTNESS_OFF_LOG` in natural log
        (`frame_brightness`; `frame_consistency`'s `brightness_off`)."""
        gains = self.frame_brightness(model)
        return [
            f
            for f in self.heldout
            if gains.get(f, 0) > 0 and abs(math.log(gains[f])) > BRIGHTNESS_OFF_LOG
        ]

    def frame_brightness(self, model) -> dict[int, float]:
        """Each frame's measured over predicted brightness under `model`, by frame index:
        the gain g minimising sum w (measured - g predicted)^2 over the views `frame_rmse`
        counts (a calibration frame's in `train`, a held-out frame's judged ones in `test`;
        NaN for a frame with none). Each view is predicted from the point's albedo in its
        other views, so g is a frame's brightness against the others': 1 where the model
        accounts for it; a spread across frames is an exposure change it lacks (a scope's
        auto-exposure, `FrameExposure`)."""
        out = {}
        for samples, judged, tested, frames in (
            (self.train, None, model, self.calibration),
            (self.test, self.judged, self.with_heldout_frames(model), self.heldout),
        ):
            gains = frame_gains(tested, samples, judged)
            out |= {f: gains.get(f, math.nan) for f in frames}
        return out

    def heldout_errors(self, model) -> SampleErrors:
        """Each tracked point's error on its held-out views under `model` as `judge` left it
        (its per-frame parameters fitted there): for comparing two judged models."""
        return heldout_map_errors(model, self.test, self.judged)

    def noise_floor(self, model) -> float:
        """The noise floor (8-bit levels) of the held-out frames under the albedo map."""
        return noise_floor_map_levels(self.capture, self.heldout, model)

    def judge(self, fit: Estimate, *, noise_floor: bool = True) -> Estimate:
        """`fit` (fitted on `train`) with its held-out RMSE (each held-out view predicted
        from the albedo of the point's other views; the calibration RMSE stays the fit's own
        over its observations), the noise floor and its frames (its per-frame parameters,
        if any, fitted on the held-out frames)."""
        model = self.with_heldout_frames(fit.model)
        rmse = {
            "calibration": fit.rmse.get("calibration", math.nan),
            "heldout": heldout_map_rmse(model, self.test, self.judged),
        }
        return dataclasses.replace(
            fit,
            model=model,
            rmse=rmse,
            noise_floor=self.noise_floor(model) if noise_floor else fit.noise_floor,
            frames=self.frames,
        )


def split_for(
    capture: "Capture | Observations",
    calibration: int | None = None,
    *,
    albedo: str = "uniform",
    max_samples: int | None = 12_000,
    heldout_samples: int | None = 40_000,
    seed: int = 0,
) -> "HeldOut | HeldOutTracks":
    """The held-out protocol for `albedo`: with `"map"`, `HeldOutTracks` (at most
    `max_samples` tracked points in the calibration frames, half `heldout_samples` anchored
    in the held-out ones); with `"uniform"`, `HeldOut`'s pixel samples."""
    if albedo == "map":
        return HeldOutTracks.split(
            capture,
            calibration,
            max_points=max_samples,
            heldout_points=None if heldout_samples is None else heldout_samples // 2,
            seed=seed,
        )
    return HeldOut.split(
        capture, calibration, max_samples=max_samples, heldout_samples=heldout_samples, seed=seed
    )


def simplest_within(
    choices: Sequence[Sequence],
    heldout_rmse: Sequence[float],
    tolerance: float = SIMPLEST_WITHIN,
    observations: "Observations | None" = None,
) -> int:
    """The index of the simplest choice (fewest components, first on ties) whose held-out
    RMSE is within `tolerance` of the lowest. `observations`: the capture's, whose clipped
    share the error gives where no error is finite."""
    lowest = min(heldout_rmse)
    if not math.isfinite(lowest):
        raise CtjaxError(
            "no model produced a finite held-out error (no held-out view the models could "
            "predict: too few unclipped views of points the calibration frames also see?)"
            + ("" if observations is None else observations.clipped_note())
        )
    within = [i for i, value in enumerate(heldout_rmse) if value <= (1 + tolerance) * lowest]
    return min(within, key=lambda i: len(choices[i]))


@dataclasses.dataclass(frozen=True)
class RightViews:
    """A stereo capture's right images as held-out views (`ctjax._right_views`): surface
    points of the left frames `frames`, followed across them, and looked for in the right
    image of each. A model is judged on the right views with every point's albedo (a
    nuisance) fitted to its other views, as on held-out frames (`heldout_map_rmse`); and,
    for comparison, on the left views of the same points the same way. The right image
    is taken at the same instant (no tissue motion between the two) from a viewpoint a
    baseline away with the light where it was: it moves V and keeps L."""

    frames: list[int]
    samples: TrackSamples  # the left and right views
    right: np.ndarray  # (M, P) as `samples.weight`: the right views
    left: TrackSamples  # the left views alone

    @classmethod
    def of(
        cls,
        capture: "Capture | Observations",
        frames: Sequence[int] | None = None,
        *,
        max_points: int | None = 12_000,
        seed: int = 0,
    ) -> "RightViews":
        """The right views of `frames` (default: all) of a stereo capture with depth in mm."""
        obs = Observations.of(capture)
        require_stereo(obs.capture)
        frames = list(range(len(obs))) if frames is None else sorted(int(f) for f in frames)
        if not frames:
            raise CtjaxError(f"{obs.root}: right views of which frames? none given")
        tracks = obs.tracks(frames=frames, max_points=max_points, seed=seed)
        left = TrackSamples.of(tracks)
        tracks, right = with_right_views(obs.capture, tracks, frames)
        samples = TrackSamples.of(tracks)
        judged_right = np.zeros(samples.weight.shape, bool)
        judged_right[:, : len(tracks)] = right.T
        if not judged_right.any():
            raise CtjaxError(
                f"{obs.root}: no tracked point is seen in a right image (check camera.json's "
                "stereo block: R, T in mm, X_right = R X_left + T)"
            )
        return cls(frames, samples, judged_right, left)

    def rmse(self, model) -> dict[str, float]:
        """RMSE (8-bit levels) of `model` on the right views (each predicted from the
        albedo of the point's other views, left and right) and on the left views of the
        same points (from the albedo of the point's other left views: the right images
        play no part);
        `views`: how many right views were judged."""
        if isinstance(getattr(model, "light", None), LightField):
            raise CtjaxError(
                "a per-pixel light field is a left-camera quantity (one direction per left "
                "pixel): it cannot predict the right camera's views"
            )
        return {
            "right": heldout_map_rmse(model, self.samples, self.right),
            "left": heldout_map_rmse(model, self.left),
            "views": int(self.right.sum()),
        }
