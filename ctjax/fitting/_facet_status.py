"""Whether the data determine the lobe about every point's own facet (`facet_status`): the
grid's ends, the gain against Lambert with its own normal chosen the same way, the even and
the odd calibration frames chosen apart, a bootstrap over the tracked points; and, once
the held-out views are judged, whether new frames see it at all, and more of it than of
each point's normal turned alone (`judged_status`); with
the facets integrated out, F_tilde's halves (`F_tilde_reasons`) and the nuisances at their
grids' ends (`nuisance_reasons`). Shared by the facet lobe (`ctjax.fitting._facet_lobe`),
the facets integrated out (`ctjax.fitting._facet_marginal`) and the lobe at their width
(`ctjax.fitting._marginal_width`); the reasons are `ctjax._determined`'s."""

import math
from collections.abc import Sequence

from .._determined import (
    HALVES_AGREE,
    MIN_LOBE_GAIN,
    PRIORITY,
    Undetermined,
    halves_apart,
    rmse_change,
    undetermined,
)
from .._status import Status

# The halves need three calibration frames each: each view judged from at least two
# others. With two each, the sinus's 6-frame sub-captures' halves agreed on one (0.106 and
# 0.112) while the two sub-captures gave 0.151 and 0.087.
MIN_FRAMES_FOR_HALVES = 6
# A choice whose bootstrap standard error is over this share of it is not determined.
MAX_RELATIVE_STDERR = 0.25
# F_tilde is a lower bound here (`FacetLobe`: 30-80% low on synthetic sparkles), so it is
# not held to sigma's precision, only to a weight told from none: its bootstrap standard
# error at most half of it (zero at least two standard errors below it). The second sinus
# video's turbinate (24 frames, 2026-12-07) read `successful` with F_tilde 0.0156 +- 0.0115
# (74%), though that spread was the grid's: F_tilde read at the nearest grid sigma jumped
# between two valleys (`chosen_on_grid` reads it at the refined sigma since: 0.0239 +-
# 0.0018); SCARED's frames 91-102: 0.0070 +- 0.00046.
MAX_F_TILDE_RELATIVE_STDERR = 0.5


def shifted_by_the_halves(sigma, f, halves, step=None) -> Undetermined | None:
    """Where the even and the odd calibration frames alone agree with each other but both
    put sigma more than `HALVES_AGREE` off its value on all of them (geometric mean): each
    half sees every point from views twice as far apart, and a width that moves with the
    frames that choose it is not the tissue's alone. On SCARED's frames 61-84 the facet lobe
    read 0.086 on all 15 calibration frames and 0.139 / 0.141 on the halves (0.059 on frames
    61-72's 8), with consecutive views 0.016 rad apart: five steps within the width, well
    sampled. On synthetic sparkles whose views are as far apart, a micro-lobe of 0.06 read
    0.049 on 15 frames and 0.055 / 0.053 on their halves (10%), one of 0.025 (below what the
    grid resolves) 0.036 and 0.047 / 0.052 (37%); the facets integrated out read 0.0631 and
    0.0657 / 0.0653 (docs/real-video.md, "Facets"). What widens the halves is the views
    that choose each facet, not the candidates: on SCARED's frames 151-162 every view judging
    with the even frames' candidates only read 0.081 (0.078 with all), each half judging with
    every frame's candidates 0.173 / 0.146 (0.153 / 0.168 with its own); on 61-72 0.082 (0.059)
    and 0.207 / 0.154 (0.201 / 0.163). `step`:
    `views_step`, quoted."""
    if halves is None or not sigma > 0:
        return None
    (a, fa), (b, fb) = halves
    if not (a > 0 and b > 0):
        return None
    shift = math.sqrt(a * b) / sigma - 1
    if abs(shift) <= HALVES_AGREE:
        return None
    peaks = f"{f / sigma**2:.3g} on all of them, {fa / a**2:.3g} / {fb / b**2:.3g} on the halves"
    spacing = ""
    if step is not None and all(math.isfinite(x) for x in step):
        spacing = (
            f"; a point's consecutive views {step[0]:.3g} rad apart on all of them, "
            f"{step[1]:.3g} / {step[2]:.3g} on the halves"
        )
    why = (
        "fewer views place each point's facet less precisely, and the lobe that predicts a "
        "view from a misplaced facet is a broader one"
        if shift > 0
        else "the frames that choose it move it"
    )
    return Undetermined(
        "sigma",
        Status.unstable,
        f"the even and the odd calibration frames alone (each point's views twice as far "
        f"apart) put sigma at {a:.3g} and {b:.3g}, {abs(shift):.0%} "
        f"{'above' if shift > 0 else 'below'} its {sigma:.3g} on all of them (over "
        f"{HALVES_AGREE:.0%}): the width depends on how many views each point has, not on "
        f"the tissue alone ({why}; the peak F_tilde/sigma^2: {peaks}{spacing})",
    )


def facet_status(
    sigma,
    f,
    sigmas,
    F_tildes,
    gain,
    halves,
    sigma_stderr=math.nan,
    unchecked=None,
    step=None,
    F_tilde_stderr=math.nan,
) -> tuple[str, tuple]:
    """The facet lobe's status and reasons (`ctjax._determined`): sigma at an end of its
    grid, a gain under `MIN_LOBE_GAIN`, halves apart or a half without the lobe (its
    F_tilde at the grid's bottom), halves that agree on a sigma away from the whole's
    (`shifted_by_the_halves`), too few calibration frames for halves (`unchecked`:
    their number), a bootstrap standard error over `MAX_RELATIVE_STDERR` of it; F_tilde at
    an end of its grid, or its bootstrap standard error over
    `MAX_F_TILDE_RELATIVE_STDERR` of it (NaN: not checked)."""
    if gain < MIN_LOBE_GAIN:  # NaN (nothing to compare with) passes
        return Status.no_lobe.name, (
            Undetermined(
                "F_tilde",
                Status.no_lobe,
                f"on the calibration frames the facet lobe {rmse_change(gain)} "
                "against Lambert with its own normal chosen the same way (under "
                f"{MIN_LOBE_GAIN:.1%} lower): no specular lobe is found, and sigma = "
                f"{sigma:.3g} is not determined by the data",
            ).to_json(),
        )
    found = undetermined(
        {"sigma": sigma},
        {},
        {"sigma": (min(sigmas), max(sigmas))} if len(sigmas) > 1 else {},
        halves=None if halves is None else {"sigma": (halves[0][0], halves[1][0])},
    )
    lacking = [
        part
        for part, (_, half_f) in zip(("even", "odd"), halves or (), strict=False)
        if len(F_tildes) > 1 and half_f <= min(F_tildes)
    ]
    if lacking and not any(u.parameter == "sigma" for u in found):
        found.append(
            Undetermined(
                "sigma",
                Status.unstable,
                f"the {' and the '.join(lacking)} calibration frames alone put F_tilde at the "
                f"bottom of its grid ({min(F_tildes):g}): the lobe is not found in "
                f"{'either half' if len(lacking) == 2 else 'one half'} of the frames",
            )
        )
    shifted = shifted_by_the_halves(sigma, f, halves, step)
    if shifted is not None and not any(u.parameter == "sigma" for u in found):
        found.append(shifted)
    if unchecked is not None and not any(u.parameter == "sigma" for u in found):
        found.append(
            Undetermined(
                "sigma",
                Status.unstable,
                f"{unchecked} calibration frames: too few to choose sigma again on halves of "
                f"at least {MIN_FRAMES_FOR_HALVES // 2} (its stability across frames is not "
                "measured)",
            )
        )
    spread = sigma_stderr / sigma
    if spread > MAX_RELATIVE_STDERR and not any(u.parameter == "sigma" for u in found):
        found.append(
            Undetermined(
                "sigma",
                Status.unstable,
                f"sigma = {sigma:.3g} has a standard error of {spread:.0%} over the tracked "
                f"points (bootstrap; over {MAX_RELATIVE_STDERR:.0%})",
            )
        )
    if len(F_tildes) > 1 and not min(F_tildes) < f < max(F_tildes):
        end = "top" if f >= max(F_tildes) else "bottom"
        found.append(
            Undetermined(
                "F_tilde",
                Status.at_bound,
                f"F_tilde = {f:g} is at the {end} of its grid ({min(F_tildes):g}, "
                f"{max(F_tildes):g}): no measurement of the lobe's weight",
            )
        )
    elif f > 0 and F_tilde_stderr > MAX_F_TILDE_RELATIVE_STDERR * f:
        found.append(
            Undetermined(
                "F_tilde",
                Status.unstable,
                f"F_tilde = {f:.3g} has a standard error of {F_tilde_stderr / f:.0%} over the "
                f"tracked points (bootstrap; over {MAX_F_TILDE_RELATIVE_STDERR:.0%}): the "
                "lobe's weight is within two standard errors of none",
            )
        )
    if not found:
        return Status.successful.name, ()
    first = min((u.status for u in found), key=PRIORITY.index)
    return first.name, tuple(u.to_json() for u in found)


def judged_status(
    status: str,
    reasons: tuple,
    rmse: float,
    lambertian: float,
    turned: float = math.nan,
    where: str = "on the held-out frames",
    then: str = "",
):
    """The status once the held-out views are judged: a lobe that predicts them no better
    than Lambert's model under the same light is not seen in new frames (`no_lobe`), however
    well the calibration frames chose it (on 24 frames of the shared sinus: 1.113x, said
    `successful` before this); nor is one that predicts them no better than Lambert's model
    with its own normal chosen the same way (`turned`, RMSE): what it takes off new frames
    is then the freedom of each point's normal, not a lobe's (the second sinus video at
    every 3rd frame: 0.992x Lambert's, `successful` on the calibration frames, where Lambert
    with its own normal read 0.929x). "Better" is by `MIN_LOBE_GAIN` at least, as on the
    calibration frames: the second sinus video at every 5th frame, one facet for the lobe
    and the diffuse term (`turned="both"`), predicted the frames the model follows in
    brightness 0.997x as far off as the turned normals, a lobe no one could tell there.
    `where`: the views judged, as the reason names them; `then`: what the reason adds."""
    if not (math.isfinite(rmse) and lambertian > 0):
        return status, reasons
    no_better = 1 - MIN_LOBE_GAIN  # a ratio above it: no better
    if rmse >= no_better * lambertian:
        why = (
            f"{where} the facet lobe predicts the views {rmse / lambertian:.3f}x "
            f"as far off as Lambert's model under the same light (not {MIN_LOBE_GAIN:.1%} "
            f"better): no specular lobe is seen in new frames{then}"
        )
    elif math.isfinite(turned) and rmse >= no_better * turned:
        why = (
            f"{where} the facet lobe predicts the views {rmse / lambertian:.3f}x "
            f"as far off as Lambert's model under the same light, and Lambert's with its own "
            f"normal chosen the same way {turned / lambertian:.3f}x: what the facets take off "
            f"new frames is each point's normal turned, not a specular lobe{then}"
        )
    else:
        return status, reasons
    found = Undetermined("F_tilde", Status.no_lobe, why)
    if status == Status.no_lobe.name:  # already: the calibration frames' reason first
        return status, (*reasons, found.to_json())
    return Status.no_lobe.name, (found.to_json(), *reasons)


def nuisance_reasons(parameter: str, name: str, value: float, grid: Sequence[float]) -> list[dict]:
    """A nuisance at an end of its grid, as `Undetermined.to_json()` (none inside)."""
    if len(grid) < 2 or min(grid) < value < max(grid):
        return []
    end = "top" if value >= max(grid) else "bottom"
    return [
        Undetermined(
            parameter,
            Status.at_bound,
            f"the {name} is at the {end} of its grid ({min(grid):g}, {max(grid):g}): the "
            "likelihood's model of the facets or of the noise misdescribes these data",
        ).to_json()
    ]


def F_tilde_reasons(f: float, split, F_tildes: Sequence[float]) -> list[dict]:
    """F_tilde's halves checked, as `Undetermined.to_json()` (empty where they agree): it
    is measured here (`facet_lobe`'s is a lower bound). Halves apart from each other, a
    half at an end of the grid (its weight not measured there), or halves that agree on a
    weight more than `HALVES_AGREE` from the whole's (geometric mean; as sigma's,
    `shifted_by_the_halves`). SCARED's frames 61-84: F_tilde 0.0727 on all 15 calibration
    frames, 0.2 (the grid's top) on each half."""
    if not split:
        return []
    a, b = split[0][1], split[1][1]
    apart = halves_apart({"F_tilde": f}, {"F_tilde": (a, b)}, set())
    if apart:
        return [u.to_json() for u in apart]
    ends = [
        (part, "top" if half >= max(F_tildes) else "bottom")
        for part, half in (("even", a), ("odd", b))
        if len(F_tildes) > 1 and not min(F_tildes) < half < max(F_tildes)
    ]
    if ends:
        parts = " and the ".join(part for part, _ in ends)
        end = ends[0][1]
        return [
            Undetermined(
                "F_tilde",
                Status.unstable,
                f"the {parts} calibration frames alone put F_tilde at the {end} of its grid "
                f"({min(F_tildes):g}, {max(F_tildes):g}) against {f:.3g} on all of them: the "
                "lobe's weight is not measured on "
                f"{'either half' if len(ends) == 2 else 'one half'} of the frames",
            ).to_json()
        ]
    if not (f > 0 and a > 0 and b > 0):
        return []
    shift = math.sqrt(a * b) / f - 1
    if abs(shift) <= HALVES_AGREE:
        return []
    return [
        Undetermined(
            "F_tilde",
            Status.unstable,
            f"the even and the odd calibration frames alone put F_tilde at {a:.3g} and "
            f"{b:.3g}, {abs(shift):.0%} {'above' if shift > 0 else 'below'} its {f:.3g} on "
            f"all of them (over {HALVES_AGREE:.0%}): the lobe's weight moves with the frames "
            "that choose it",
        ).to_json()
    ]
