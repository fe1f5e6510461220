"""The facet lobe at the marginal likelihood's width (`at_the_marginal_width`), and the
commands' lines for the marginal (`facet_marginal_line`) and for it."""

from .._determined import PRIORITY
from .._status import Status
from ._facet_lobe import FacetLobe
from ._facet_status import F_tilde_reasons


def facet_marginal_line(summary: dict) -> str:
    """One line for a command's output from `FacetMarginal.to_json()`."""
    halves = summary["halves"]
    split = (
        f"; halves sigma {halves['even_frames']['sigma']:.3g} / "
        f"{halves['odd_frames']['sigma']:.3g}, F_tilde {halves['even_frames']['F_tilde']:.3g} / "
        f"{halves['odd_frames']['F_tilde']:.3g} (even / odd calibration frames)"
        if halves
        else ""
    )
    along = summary.get("contiguous_halves")
    if along:
        split += (
            f"; sigma {along['first_half']['sigma']:.3g} / {along['second_half']['sigma']:.3g} "
            "(first / second half)"
        )
    return (
        f"the facets integrated out (a marginal likelihood on the calibration frames): sigma "
        f"{summary['sigma']:.3g}, F_tilde {summary['F_tilde']:.3g} (an upper bound), the "
        f"facets' spread sigma_M {summary['facet_prior_sigma']:.3g}, noise "
        f"{summary['noise_levels']:.3g} levels, {summary['gain_nats_per_value']:.3g} nats per "
        f"value over no lobe{split}; status {summary['status']}"
        + "".join(f"; {u['reason']}" for u in _first_of_status(summary)[:1])
    )


def _first_of_status(summary: dict) -> list[dict]:
    """The reasons behind the status first (the line shows one)."""
    reasons = summary["undetermined"]
    return sorted(reasons, key=lambda u: u.get("status") != summary["status"])


# The marginal's reasons that concern the width (its F_tilde is an upper bound, and the
# lobe at its width chooses its own).
_WIDTH_REASONS = ("sigma", "sigma_M", "noise_levels")


def at_the_marginal_width(lobe: FacetLobe, marginal: dict) -> dict:
    """The facet lobe with sigma held at the marginal likelihood's, as JSON: `lobe` is
    `facet_lobe` on a grid of that one width (its F_tilde and every point's facet chosen by
    the facet protocol, judged on the held-out views), `marginal` `FacetMarginal.to_json()`.
    Each estimator for what it reads consistently: the width from the marginal (within 6%
    of synthetic truth, where the facet protocol's follows the views' spacing), the weight
    and the facets from the protocol at that width. The status is the worst of the
    marginal's reasons about the width (sigma, the facets' spread, the noise), the
    fixed-width lobe's own (its grid, its gain against Lambert) and its F_tilde's halves,
    checked as the marginal's (`F_tilde_reasons`: F_tilde is what is measured here). On
    SCARED's frames 61-84 (docs/real-video.md): sigma 0.150 (halves 0.175 / 0.176), F_tilde
    0.035 (halves 0.032 / 0.028), 0.751x Lambert's test error under the same light; on
    61-72 sigma 0.119, F_tilde 0.021, halves 0.010 / 0.016: `unstable`."""
    F_tildes = sorted({f for _, f in lobe.calibration_rmse})
    width = [u for u in marginal["undetermined"] if u["parameter"] in _WIDTH_REASONS]
    reasons = [*width, *lobe.undetermined, *F_tilde_reasons(lobe.F_tilde, lobe.halves, F_tildes)]
    statuses = [Status[u["status"]] for u in reasons]
    status = min(statuses, key=PRIORITY.index).name if statuses else Status.successful.name
    dropped = ("sigma_stderr", "at_bound", "calibration_rmse_by_candidates", "calibration_rgb_rmse")
    summary = {key: value for key, value in lobe.to_json().items() if key not in dropped}
    del summary["halves"]
    summary["F_tilde_halves"] = [f for _, f in lobe.halves] if lobe.halves else None
    summary["sigma_halves"] = (
        [part["sigma"] for part in marginal["halves"].values()] if marginal["halves"] else None
    )
    along = marginal.get("contiguous_halves")
    summary["sigma_contiguous_halves"] = (
        [part["sigma"] for part in along.values()] if along else None
    )
    summary.update(status=status, undetermined=reasons, sigma_from="facet_marginal")
    return summary


def at_the_marginal_width_line(summary: dict) -> str:
    """One line for a command's output from `at_the_marginal_width`."""

    def halves(name):
        parts = summary[f"{name}_halves"]
        return f" (halves {parts[0]:.3g} / {parts[1]:.3g})" if parts else ""

    return (
        f"the facet lobe at the marginal's width: sigma {summary['sigma']:.3g}"
        f"{halves('sigma')}, F_tilde {summary['F_tilde']:.3g}{halves('F_tilde')} chosen on the "
        f"calibration frames: held-out RMSE {summary['heldout_rgb_rmse']:.2f} levels, "
        f"{summary['ratio']:.3f}x Lambert's under the same light "
        f"({summary['lambertian_same_light_rgb_rmse']:.2f}"
        + (
            ""
            if summary.get("control_ratio") is None
            else f"; with another point's facets {summary['control_ratio']:.3f}x"
        )
        + f"); status {summary['status']}"
        + "".join(f"; {u['reason']}" for u in summary["undetermined"][:1])
    )
