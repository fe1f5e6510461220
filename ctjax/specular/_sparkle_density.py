"""Sigma from where the highlights are, not from how bright they are (issue #42, item 1).

Wet tissue shows its specular lobe as *sparkles*: small facets, far below what a normal map
from structure-from-motion resolves, each lit when its own normal lies along the half
vector H. Under Beckmann's model (paper eq. 2) the share of a surface's facets whose normal
lies in a small cone about H, at an angle theta_h between the surface's normal N and H, is
`D(theta_h) cos theta_h`, so the chance that a pixel is in the specular set S is

    P(q in S | theta_h) = a exp(-tan^2 theta_h / sigma^2) / cos^3 theta_h,   0 < a <= 1   (*)

`a` folds in the cone's size (the sharpness of each facet's own reflection, the highlight
rule's threshold, the exposure). `sparkle_density` fits (*) by maximum likelihood over
every pixel with a normal (binomial: in S or not) in every frame: sigma comes from *where*
the highlights are, never from their clipped, gamma-encoded, exposure-varying values.
The light is at the lens (the paper's assumption on S, section 5), so H = V, the pixel's
view direction.

Limits, measured on synthetic captures (benchmarks/lobe_ideas.py):

- (*) holds for sparkles (one facet per pixel or a few). A smooth surface with a broad lobe
  shows one solid highlight whose edge is where the lobe falls below the highlight rule's
  threshold: S is then a disc in theta_h, the fitted `a` reaches 1, and sigma is not
  determined by this method (status `solid_highlights`; fit the intensities,
  `ctjax.estimation.fit_capture`).
- Errors of the normals broaden the fitted lobe: roughly sigma_fit^2 = sigma^2 + e^2, e the
  normals' RMS error (tan of the angle). Given `normal_error_deg`, `sigma_corrected`
  removes it: within 5% of the truth up to 5 degrees RMS, within 15% at 10; at 20 degrees
  and more it is not a correction (status `broadened`). Without it, sigma is an upper
  bound (to about 5%).
- Where the normals do not see the highlights (S no nearer to H than the other pixels, as
  on real sinus frames with SfM normals), nothing is measured (status `undetermined`).
"""

import dataclasses
import math

import numpy as np

from .._errors import CtjaxError, ParameterError
from ..io import Capture
from ._capture_sets import MaskOptions, capture_sets
from ._specular_set import SpecularSets

# The fitted range of sigma; an estimate within 1% of either end is at the bound.
SIGMA_RANGE = (1e-3, 3.0)
# Share of the normals' error sigma^2 may lose to the correction before it is no longer one.
_MAX_BROADENING = 0.5
# Even and odd frames further apart than this (relative) are `unstable`.
_MAX_HALVES_DIFFERENCE = 0.25
# The shape check (`peak_away`): 10-degree bins holding 5% of S, and how far above (*)'s
# fall from the first bin a bin's share of S may stand.
_PEAK_BIN_DEG = 10.0
_PEAK_MIN_SHARE = 0.05
_PEAK_MIN_HITS = 20
_MAX_PEAK_RATIO = 1.25
# The cos^-3 factor of (*): the facets' density D cos theta_h in solid angle.
_COS_POWER = 3.0


@dataclasses.dataclass(frozen=True)
class SparkleDensity:
    """The fit of (*) (module docstring). `sigma`: Beckmann roughness of the sparkles'
    density (an upper bound where the normals are off); `sigma_rel_stderr`: its relative
    standard error (binomial likelihood); `rate`: `a`, P(S) where N = H; `sigma_corrected`:
    sigma with the normals' error removed (None without `normal_error_deg`); `halves`:
    sigma of the even and of the odd frames apart (None for one frame); the counts and the
    median theta_h (degrees) of all the pixels and of S; `peak_ratio`: how far the share of S
    at `peak_at_deg` stands above (*)'s fall from theta_h = 0 (`peak_away`; 1: nowhere);
    `status`: `successful`, `upper_bound` (no `normal_error_deg` given), `undetermined`,
    `solid_highlights`, `misaligned`, `broadened` or `unstable`, `reason` saying why."""

    sigma: float
    sigma_rel_stderr: float | None
    rate: float
    sigma_corrected: float | None
    halves: tuple[float, float] | None
    n_pixels: int
    n_specular: int
    theta_h_median_deg: float
    theta_h_median_specular_deg: float
    peak_ratio: float
    peak_at_deg: float
    status: str
    reason: str

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def half_angles(capture: Capture, sets: list[SpecularSets]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame, (theta_h in radians, in S) of every pixel with a normal, in the scene, not
    clipped outside S and facing the camera; H = V (the light at the lens)."""
    if len(sets) != len(capture.frames):
        raise ParameterError(f"{len(sets)} sets of masks for {len(capture.frames)} frames")
    if not capture.has_geometry:
        raise CtjaxError(f"{capture.root}: frames without normals (ctjax reconstruct first)")
    camera = capture.camera
    out = []
    for frame, masks in zip(capture.frames, sets, strict=True):
        h, w = frame.image.shape[:2]
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        ray = np.stack(
            [
                (u - float(camera.cx)) / float(camera.fx),
                (v - float(camera.cy)) / float(camera.fy),
                np.ones_like(u),
            ],
            axis=-1,
        )
        view = -ray / np.linalg.norm(ray, axis=-1, keepdims=True)
        valid = frame.geometry_mask & ~masks.saturated
        cos = np.sum(np.where(valid[..., None], frame.normals, 0.0) * view, axis=-1)
        valid &= cos > 0
        out.append((np.arccos(np.minimum(cos[valid], 1.0)), masks.specular[valid]))
    return out


def sparkle_density_of_angles(
    theta_h: np.ndarray,
    specular: np.ndarray,
    *,
    bins: int = 400,
    max_theta_deg: float = 80.0,
    standard_error: bool = True,
) -> tuple[float, float, float | None]:
    """(sigma, a, relative standard error of sigma) of (*) fitted to pixels at half angles
    `theta_h` (radians, 1-D), `specular` saying which are in S, binned in `bins` bins of
    theta_h up to `max_theta_deg` (pixels beyond are left out); without `standard_error`
    the third is None (the halves' check needs only sigma).

    Raises `ParameterError` for shapes that disagree, non-finite or out-of-range angles, an
    empty S or an S that holds every pixel.
    """
    theta_h = np.asarray(theta_h, np.float64)
    specular = np.asarray(specular)
    if theta_h.ndim != 1 or specular.shape != theta_h.shape:
        raise ParameterError(
            f"theta_h and specular must be 1-D and alike, got {theta_h.shape} and {specular.shape}"
        )
    if specular.dtype != bool:
        raise ParameterError(f"specular must be boolean, got {specular.dtype}")
    if not np.all(np.isfinite(theta_h)):
        raise ParameterError("theta_h has non-finite values (NaN normals?)")
    if np.any(theta_h < 0) or np.any(theta_h > math.pi / 2):
        raise ParameterError("theta_h must lie in [0, pi/2] (normals facing the camera)")
    if not 0 < max_theta_deg < 90 or bins < 2:
        raise ParameterError(f"need 0 < max_theta_deg < 90 and bins >= 2, got {max_theta_deg}")
    edges = np.linspace(0.0, math.radians(max_theta_deg), bins + 1)
    total, _ = np.histogram(theta_h, edges)
    hits, _ = np.histogram(theta_h[specular], edges)
    if hits.sum() == 0:
        raise ParameterError("S is empty (no specular pixel with a normal): no sparkle to count")
    if hits.sum() == total.sum():
        raise ParameterError("every pixel is in S: no sparkle density to fit")
    keep = total > 0
    centre = 0.5 * (edges[1:] + edges[:-1])[keep]
    tan2 = np.tan(centre) ** 2
    log_cos = -_COS_POWER * np.log(np.cos(centre))
    total, hits = total[keep].astype(np.float64), hits[keep].astype(np.float64)
    lo, hi = np.log(SIGMA_RANGE)

    def nll(log_a, log_s):
        """The negative log-likelihood at every (log a, log sigma) of two broadcast arrays."""
        log_a, log_s = np.asarray(log_a)[..., None], np.asarray(log_s)[..., None]
        log_p = np.minimum(log_a + log_cos - tan2 * np.exp(-2 * log_s), -1e-12)
        return -np.sum(hits * log_p + (total - hits) * np.log(-np.expm1(log_p)), axis=-1)

    # The rate `a` is at most 1 (a probability where N = H).
    (log_a, log_s), _ = _grid_minimum(nll, [(-20.0, 0.0), (lo, hi)], points=21)
    if not standard_error:
        return float(math.exp(log_s)), float(math.exp(log_a)), None
    # Relative standard error: the likelihood's curvature in log sigma, `a` profiled out
    # (nll is convex in log a at a fixed sigma: one minimum).
    step = 1e-3

    def profile(ls):
        return _grid_minimum(lambda la: nll(la, ls), [(-40.0, 0.0)])[1]

    curvature = (profile(log_s + step) + profile(log_s - step) - 2 * profile(log_s)) / step**2
    rel = 1 / math.sqrt(curvature) if curvature > 0 else None
    return float(math.exp(log_s)), float(math.exp(log_a)), rel


def _grid_minimum(cost, bounds, *, points: int = 41, tolerance: float = 1e-7):
    """(argument, value) of the minimum of `cost` (a function of one array per axis, all
    broadcast alike, giving the cost at each point) within `bounds` ((lo, hi) per axis): a
    grid of `points` per axis, then finer grids of 11 points over two steps either side of
    the last best point (the step shrinks 2.5-fold a round; where the best point is on
    the window's edge, the window moves with the same step), until the step is
    `tolerance` of the range. Array operations only: scipy.optimize, its import and the
    threaded BLAS its L-BFGS-B calls, made this fit take up to a second."""
    lo = np.array([b[0] for b in bounds], np.float64)
    hi = np.array([b[1] for b in bounds], np.float64)
    low, high, n = lo, hi, points
    for _ in range(200):
        axes = [np.linspace(a, b, n) for a, b in zip(low, high, strict=True)]
        values = cost(*np.meshgrid(*axes, indexing="ij"))
        index = np.unravel_index(int(np.argmin(values)), values.shape)
        best = np.array([axis[i] for axis, i in zip(axes, index, strict=True)])
        step = (high - low) / (n - 1)
        if np.all(step <= tolerance * (hi - lo)):
            break
        i = np.array(index)
        edge = ((i == 0) & (low > lo)) | ((i == n - 1) & (high < hi))
        half = np.where(edge, 5 * step, 2 * step)
        low, high, n = np.maximum(best - half, lo), np.minimum(best + half, hi), 11
    return best, float(values[index])


def peak_away(
    theta_h: np.ndarray, specular: np.ndarray, sigma: float, rate: float
) -> tuple[float, float]:
    """Whether the highlights are densest away from N = H: over 10-degree bins of theta_h
    that hold at least 5% of S, the largest ratio of a bin's measured share of S (at 20
    degrees or more) to the first bin's, over the same ratio under (*), and that bin's
    centre (degrees); (1, 0) where the first bin holds under 20 pixels of S, or where no
    bin is significantly (3 binomial standard
    deviations) above the first one's share times (*)'s ratio. Under (*) with sigma under
    0.8 the share falls with theta_h, and errors of the normals that are random about the
    truth keep it falling; a peak away from 0 says the normals (or the light) are tilted
    against the highlights."""
    edges = np.radians(np.arange(0.0, 90.0 + _PEAK_BIN_DEG, _PEAK_BIN_DEG))
    index = np.clip(np.digitize(theta_h, edges) - 1, 0, edges.size - 2)
    p = np.minimum(
        rate * np.exp(-(np.tan(theta_h) ** 2) / sigma**2) / np.cos(theta_h) ** _COS_POWER, 1.0
    )
    total = np.bincount(index, minlength=edges.size - 1).astype(np.float64)
    hits = np.bincount(index[specular], minlength=edges.size - 1).astype(np.float64)
    # (*) averaged over each bin's pixels (not at its centre: the lobe changes within a bin).
    model = np.bincount(index, weights=p, minlength=edges.size - 1) / np.maximum(total, 1)
    if hits[0] < _PEAK_MIN_HITS or model[0] <= 0:
        return 1.0, 0.0  # too few highlights where N = H to compare with
    share = hits / np.maximum(total, 1)
    expected = share[0] * model / model[0]  # each bin's share, from the first bin's
    spread = np.sqrt(expected * (1 - np.minimum(expected, 1)) / np.maximum(total, 1))
    spread = np.hypot(spread, expected * np.sqrt(max(1 - share[0], 0) / max(hits[0], 1)))
    above = (
        (np.arange(total.size) >= 2)
        & (hits >= max(_PEAK_MIN_SHARE * hits.sum(), _PEAK_MIN_HITS))
        & (share - expected > 3 * spread)
    )
    if not above.any():
        return 1.0, 0.0
    ratio = np.where(above, share / np.maximum(expected, 1e-300), 0.0)
    k = int(np.argmax(ratio))
    return float(ratio[k]), float(np.degrees(0.5 * (edges[k] + edges[k + 1])))


def sparkle_density(
    capture: Capture,
    masks: MaskOptions | None = None,
    *,
    sets: list[SpecularSets] | None = None,
    normal_error_deg: float | None = None,
    max_theta_deg: float = 80.0,
) -> SparkleDensity:
    """Beckmann's sigma from the density of the highlights (S) over the angle theta_h
    between each pixel's normal and H, every frame of `capture` together (module
    docstring), with the even and the odd frames apart as a check.

    `sets`: S of every frame (default: `capture_sets(capture, masks)`, `masks` by default
    `MaskOptions()`, as `ctjax masks` finds them). `normal_error_deg`:
    the normals' RMS error in degrees, where it is known (e.g. measured against another
    shape): `sigma_corrected` removes the broadening it causes.

    Raises `CtjaxError` for a capture without normals, `ParameterError` for an empty S, NaN
    normals where the geometry is said to be valid, or a bad `normal_error_deg`.
    """
    if normal_error_deg is not None and not (
        math.isfinite(normal_error_deg) and 0 <= normal_error_deg < 90
    ):
        raise ParameterError(f"normal_error_deg must be in [0, 90), got {normal_error_deg}")
    if sets is None:
        sets = capture_sets(capture, MaskOptions() if masks is None else masks)
    angles = half_angles(capture, sets)
    theta = np.concatenate([a for a, _ in angles])
    in_s = np.concatenate([s for _, s in angles])
    if not in_s.any():
        raise ParameterError(
            f"{capture.root}: S is empty (no specular pixel with a normal) in all "
            f"{len(angles)} frame(s): no sparkle to count"
        )
    fit = dict(bins=400, max_theta_deg=max_theta_deg)
    sigma, rate, rel = sparkle_density_of_angles(theta, in_s, **fit)
    halves = None
    if len(angles) > 1:
        parts = []
        for parity in (0, 1):
            t = np.concatenate([a for a, _ in angles[parity::2]])
            s = np.concatenate([s for _, s in angles[parity::2]])
            parts.append(
                sparkle_density_of_angles(t, s, **fit, standard_error=False)[0]
                if s.any()
                else math.nan
            )
        halves = (parts[0], parts[1])
    corrected = None
    if normal_error_deg is not None:
        noise2 = math.tan(math.radians(normal_error_deg)) ** 2
        corrected = math.sqrt(max(sigma**2 - noise2, 0.0))
    median_all = math.degrees(float(np.median(theta)))
    median_s = math.degrees(float(np.median(theta[in_s])))
    fitted = theta <= math.radians(max_theta_deg)
    peak, peak_at = peak_away(theta[fitted], in_s[fitted], sigma, rate)
    fit = SparkleDensity(
        sigma=sigma,
        sigma_rel_stderr=rel,
        rate=rate,
        sigma_corrected=corrected,
        halves=halves,
        n_pixels=int(theta.size),
        n_specular=int(in_s.sum()),
        theta_h_median_deg=median_all,
        theta_h_median_specular_deg=median_s,
        peak_ratio=peak,
        peak_at_deg=peak_at,
        status="",
        reason="",
    )
    status, reason = _status(fit, normal_error_deg)
    return dataclasses.replace(fit, status=status, reason=reason)


def _status(fit: SparkleDensity, normal_error_deg: float | None) -> tuple[str, str]:
    lo, hi = SIGMA_RANGE
    sigma = fit.sigma
    if fit.theta_h_median_specular_deg >= fit.theta_h_median_deg:
        return "undetermined", (
            f"S lies no nearer to H than the other pixels (median theta_h "
            f"{fit.theta_h_median_specular_deg:.1f} vs {fit.theta_h_median_deg:.1f} degrees): "
            "the normals do not see the highlights"
        )
    if sigma >= 0.99 * hi or sigma <= 1.01 * lo:
        return "undetermined", f"sigma = {sigma:.4g} is at the bound of {SIGMA_RANGE}"
    if fit.rate >= 0.99:
        return "solid_highlights", (
            "P(S) reaches 1 where N = H: S is a solid highlight cut by a threshold, not a "
            "density of sparkles; its edge does not give sigma (fit the intensities)"
        )
    if fit.peak_ratio > _MAX_PEAK_RATIO:
        return "misaligned", (
            f"S is densest away from N = H (at theta_h = {fit.peak_at_deg:.0f} degrees, "
            f"{fit.peak_ratio:.2f}x Beckmann's fall from 0): the normals (or the light) are "
            "tilted against the highlights; sigma is not measured"
        )
    if normal_error_deg is not None:
        noise2 = math.tan(math.radians(normal_error_deg)) ** 2
        if noise2 > _MAX_BROADENING * sigma**2:
            return "broadened", (
                f"the normals' error ({normal_error_deg:.1f} degrees) makes over "
                f"{_MAX_BROADENING:.0%} of sigma^2 = {sigma**2:.3g}: the lobe is the normals' "
                "error, not the tissue's; sigma is an upper bound"
            )
    if fit.halves is not None:
        difference = abs(fit.halves[0] - fit.halves[1]) / max(min(fit.halves), 1e-12)
        if not difference <= _MAX_HALVES_DIFFERENCE:
            return "unstable", (
                f"the even and odd frames disagree: sigma {fit.halves[0]:.3g} vs "
                f"{fit.halves[1]:.3g}"
            )
    if normal_error_deg is None:
        return "upper_bound", (
            "the normals' error (not given) broadens the lobe: the tissue's sigma is about "
            "sqrt(sigma^2 - e^2), e the tan of their RMS error (normal_error_deg)"
        )
    return "successful", "sigma from the sparkles' density over theta_h"


# The block's statuses where nothing was fitted (beside `SparkleDensity.status`'s).
NO_NORMALS = "no_normals"
EMPTY_S = "empty_specular_set"
NOT_MEASURED = "not_measured"


def sparkle_density_summary(capture: Capture, sets: list[SpecularSets]) -> dict:
    """`ctjax fit`'s `sparkle_density` block: the fit of (*) on the sets the intensity fit
    used (`sets`, one per frame), as JSON (sigma, its relative standard error, the rate,
    the even and odd frames' sigma, the counts and the median theta_h, status and reason).
    Never raises for the capture's content: without normals (`no_normals`), with an empty S
    among the pixels with a normal (`empty_specular_set`) or where the fit cannot be made
    (`not_measured`), the block says so in `status` and `reason`, its numbers None."""
    try:
        fit = sparkle_density(capture, sets=sets)
    except ParameterError as error:
        empty = "S is empty" in str(error)
        status = EMPTY_S if empty else NOT_MEASURED
        return _unmeasured(status, str(error), sets)
    except CtjaxError as error:
        status = NO_NORMALS if not capture.has_geometry else NOT_MEASURED
        return _unmeasured(status, str(error), sets)
    out = fit.to_json()
    del out["sigma_corrected"]  # no normal_error_deg in `ctjax fit`
    halves = fit.halves
    out["halves"] = (
        None
        if halves is None
        else {
            "even_frames": _finite(halves[0]),
            "odd_frames": _finite(halves[1]),
        }
    )
    return {
        "method": "sigma from where the highlights are over theta_h "
        "(ctjax.specular.sparkle_density; sparkles, not solid highlights)",
        **out,
    }


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _unmeasured(status: str, reason: str, sets: list[SpecularSets]) -> dict:
    return {
        "method": "sigma from where the highlights are over theta_h "
        "(ctjax.specular.sparkle_density)",
        "sigma": None,
        "sigma_rel_stderr": None,
        "rate": None,
        "halves": None,
        "n_pixels": None,
        "n_specular": sum(int(s.specular.sum()) for s in sets),
        "theta_h_median_deg": None,
        "theta_h_median_specular_deg": None,
        "status": status,
        "reason": reason,
    }


def sparkle_density_line(block: dict) -> str:
    """One line of `ctjax fit`'s output for its `sparkle_density` block."""
    if block["sigma"] is None:
        return f"sparkle density: not measured ({block['status']}): {block['reason']}"
    halves = block["halves"]
    split = ""
    if halves is not None:
        even, odd = (
            "n/a" if v is None else f"{v:.2f}"
            for v in (halves["even_frames"], halves["odd_frames"])
        )
        split = f" (even {even} / odd {odd})"
    return (
        f"sparkle density: sigma {block['sigma']:.2f}{split}, {block['status']}: {block['reason']}"
    )
