"""The leading candidates of a diagnosis told apart: the best against the base, and the others
that improve on the base against the best, on the same held-out samples (`ctjax._paired`)."""

from .._paired import paired_difference, z_score
from .._result import Estimate

# How the leading candidates are told apart: on the held-out samples, pair by pair, in
# standard errors of the difference of their mean squared errors (`ctjax._paired`: blocks
# of the image as independent draws). Candidates within this many of the best predict the
# held-out frames as well as it does; at most `COMPARED` candidates that improve on the base
# are compared (one run of a compiled program each).
TOLD_APART_Z = 2.0
COMPARED = 6


def compared(heldout, base: Estimate, results: list[Estimate]) -> tuple[dict | None, list]:
    """The best of `results` (sorted, judged on `heldout`) against the base, and the others
    that improve on the base against the best, on the same held-out samples: its gain in
    standard errors, and those within `TOLD_APART_Z` of it (see `Diagnosis`).

    A candidate judged on other samples than the base's (`details["judged_on"]`: the
    `albedo_texture` candidate of a one-albedo diagnosis, judged on the map's tracked views,
    the base on pixels) is not paired: as the best, its `z` is None and it names those
    samples (`judged_on`), and no other candidate is compared with it; behind the best, it
    is left out of `close`. (Paired on the base's pixels, the map's model, which has no
    albedo there, read 10 standard errors worse than the base on the shared sinus while its
    held-out RMSE was 74% lower on its own samples.)"""
    better = [c for c in results[:COMPARED] if c.details["improvement"] > 0]
    if not better:
        return None, []
    if "judged_on" in better[0].details:
        leading = {
            "effect": better[0].details["effect"],
            "improvement": better[0].details["improvement"],
            "z": None,
            "judged_on": better[0].details["judged_on"],
        }
        return leading, []
    best = heldout.heldout_errors(better[0].model)

    def row(c: Estimate, behind) -> dict:
        z = z_score(*paired_difference(behind, best))
        return {"effect": c.details["effect"], "improvement": c.details["improvement"], "z": z}

    leading = row(better[0], heldout.heldout_errors(base.model))
    paired = [c for c in better[1:] if "judged_on" not in c.details]
    close = [row(c, heldout.heldout_errors(c.model)) for c in paired]
    return leading, [c for c in close if c["z"] is None or c["z"] < TOLD_APART_Z]
