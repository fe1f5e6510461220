"""The near light's candidate models: its falloff sets, where its offset is fitted, the
starts of a fit, and what is said when the data show no offset. Shared by the albedo map's
fit (`near_light_map`) and the paper's one albedo (`near_light_uniform`)."""

import itertools

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._errors import CtjaxError
from .._units import length_unit_of
from ..fitting import ShadingModel, paper_model, roughness_variants
from ..heldout import SIMPLEST_WITHIN, median_depth_mm
from ..io import Capture
from ..lights import AbstractFalloff, InverseSquare, LensPlaneLight, PointLight, SpotFalloff
from ..lights._point import offset_starts
from ..lobes import Lambertian
from ..lobes._diffuse import with_diffuse_lobe
from ..observations import Observations


def falloff_choices(capture: "Capture | Observations") -> list[tuple[AbstractFalloff, ...]]:
    """Every subset of inverse-square (referenced at the working distance) and spot falloff:
    what `calibrate_near_light` compares by default."""
    factors = (InverseSquare(median_depth_mm(capture)), SpotFalloff(2.0))
    return [c for r in range(len(factors) + 1) for c in itertools.combinations(factors, r)]


FALLOFF_NAMES = ("auto", "none", "inverse_square", "spot", "inverse_square+spot")


def named_falloff(name: str, capture: "Capture | Observations"):
    """A falloff set by name (`FALLOFF_NAMES`, the command line's `--falloff`): None for
    "auto" (every set of `falloff_choices`, chosen on held-out frames), else its factors."""
    if name not in FALLOFF_NAMES:
        raise CtjaxError(f"falloff must be one of {', '.join(FALLOFF_NAMES)}, got {name!r}")
    if name == "auto":
        return None
    return next(c for c in falloff_choices(capture) if falloff_name(c) == name)


def falloff_name(falloff: tuple[AbstractFalloff, ...]) -> str:
    return "+".join(f.name for f in falloff) or "none"


def paper_start(diffuse: type[Lambertian], effects=()) -> ShadingModel:
    """The paper's model with `diffuse` as its diffuse term (its shape at the middle of its
    domain) and the image `effects` (`AbstractImageEffect`s at their start), a fit's start."""
    model = paper_model(1.0, 0.3, 0.2)
    model = eqx.tree_at(lambda m: m.brdf, model, with_diffuse_lobe(model.brdf, diffuse))
    return eqx.tree_at(lambda m: m.effects, model, tuple(effects))


# Where the light's offset is fitted: in the lens plane (`LensPlaneLight`, the default: the
# scope's light leaves the face of its tip) or anywhere (`PointLight`).
OFFSET_AXES = ("lens_plane", "free")


def light_at(offset, falloff, axes: str):
    """The light at `offset` (x, y, z) with `falloff`, fitted along `axes` (`OFFSET_AXES`)."""
    if axes == "lens_plane":
        return LensPlaneLight(jnp.asarray(offset[:2], float), falloff=tuple(falloff))
    return PointLight(jnp.asarray(offset, float), falloff=tuple(falloff))


def position_name(model) -> str:
    """The dotted name of `model`'s light position (`hold` and `freeze` take it)."""
    return f"light.{type(model.light).position_field}"


def offset_axes_of(model) -> str:
    """Where `model`'s light offset was fitted (`OFFSET_AXES`)."""
    return "lens_plane" if isinstance(model.light, LensPlaneLight) else "free"


def position_stderr(stderr: dict, model, default):
    """The standard errors of `model`'s light position along x, y, z (0 along the axis in
    the lens plane, where it is not fitted) from `stderr` (by dotted name), or `default`."""
    errors = stderr.get(position_name(model))
    if errors is None:
        return default
    return [*errors, 0.0] if len(errors) == 2 else list(errors)


def near_light_starts(
    falloff: tuple[AbstractFalloff, ...],
    capture,
    diffuse: type[Lambertian] = Lambertian,
    axes: str = "lens_plane",
    effects=(),
) -> list[ShadingModel]:
    """Starting models from every offset of `offset_starts` and several roughnesses, with
    the image `effects` at their start."""
    starts = []
    unit = length_unit_of(capture)
    for offset in offset_starts(unit, median_depth_mm(capture)):
        light = light_at(offset, falloff, axes)
        starts.extend(
            roughness_variants(eqx.tree_at(lambda m: m.light, paper_start(diffuse, effects), light))
        )
    return starts


def falloff_sets(capture, falloff) -> list[tuple[AbstractFalloff, ...]]:
    if falloff is None:
        choices = falloff_choices(capture)
    elif all(isinstance(f, AbstractFalloff) for f in falloff):
        choices = [tuple(falloff)]
    else:
        choices = [tuple(c) for c in falloff]
    for choice in choices:
        for factor in choice:
            if not isinstance(factor, AbstractFalloff):
                raise CtjaxError(f"a falloff must be an AbstractFalloff, got {factor!r}")
    return choices


def at_the_lens(
    falloff: tuple[AbstractFalloff, ...], diffuse: type[Lambertian], axes: str, effects=()
) -> list[ShadingModel]:
    light = light_at((0.0, 0.0, 0.0), falloff, axes)
    start = paper_start(diffuse, effects)
    return roughness_variants(eqx.tree_at(lambda m: m.light, start, light))


def no_offset(result, offset, stderr, offset_fit, lens_fit, unit) -> None:
    """The light at the lens as the estimate: the bound on an offset, and the warning."""
    bound = float(np.linalg.norm(offset) + 2 * np.linalg.norm(stderr))
    # None (JSON null) where the standard errors could not be computed: no bound.
    result.details["offset_bound_mm"] = bound if np.isfinite(bound) else None
    errors = f"{lens_fit.heldout_rmse:.3f} vs {offset_fit.heldout_rmse:.3f} levels held-out"
    if offset_fit.heldout_rmse >= (1 - SIMPLEST_WITHIN) * lens_fit.heldout_rmse:
        why = f"the light at the lens explains the held-out frames about as well ({errors})"
    elif not np.all(np.isfinite(stderr)):
        why = f"the offset's standard errors could not be computed (at the lens {errors})"
    else:
        why = f"the fitted offset is within 2 standard errors of 0 (at the lens {errors})"
    limit = (
        f"an offset below {bound:.2g} {unit} cannot be told from none"
        if np.isfinite(bound)
        else "the data set no bound on an offset (its standard errors could not be computed)"
    )
    result.warnings.append(
        f"no light offset detected: {why}; "
        f"fitted offset {_shown(offset)} +- {_shown(stderr)} {unit}: {limit}"
    )


def _shown(values) -> str:
    """Two significant digits each: a standard error of 0.0049 is not "0.0"."""
    return "[" + ", ".join(f"{float(v):.2g}" for v in np.ravel(values)) + "]"


# Held-out residuals above this multiple of their noise floor: the standard errors, which
# take the residuals for noise, are said not to bound the parameters.
MISFIT_TIMES = 3.0


def warn_of_misfit(result, hint: str) -> None:
    """A warning on `result` (an `Estimate` with its held-out RMSE and noise floor) where
    its held-out residuals exceed `MISFIT_TIMES` their noise floor: its standard errors
    count that misfit as noise. `hint`: what may be missing, said in parentheses."""
    floor = result.noise_floor
    times = result.heldout_rmse / floor if floor and floor > 0 else float("nan")
    if times > MISFIT_TIMES:
        result.warnings.append(
            f"the model leaves {result.heldout_rmse:.3g} levels on the held-out frames, "
            f"{times:.0f}x their noise floor ({floor:.3g}): the standard errors count that "
            f"misfit as noise and understate what the data leave open ({hint})"
        )
