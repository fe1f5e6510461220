"""The specular lobes an evaluation judged on its test frames, side by side, each against
Lambert's model under the same light: the paper's lobe about the reconstruction's normals
and, where they were judged (`evaluate(facets=...)`), the lobe about every tracked point's
own facet at its own width and at the width with the facets integrated out.

On real da Vinci frames these disagree in a way no single figure shows: on SCARED the
paper's lobe is determined and predicts the test frames at 0.94-1.0x Lambert's error, while
the facet lobe, determined too, predicts them at 0.79x (docs: real endoscopic video). Read
from `Evaluation.to_json()`'s blocks, so that the JSON and the command say the same."""

import math

# (key, what the lobe is about), in the order they are judged.
LOBES = (
    ("normals", "the reconstruction's normals"),
    ("facets", "each point's own facet"),
    ("facets_at_the_marginal_width", "each point's own facet, at the marginal's width"),
)


def _largest(value) -> float | None:
    values = [value] if isinstance(value, int | float) else list(value or [])
    values = [float(v) for v in values if v is not None]
    return max(values) if values else None


def _row(name, sigma, F_tilde, rmse, reference, status) -> dict | None:
    if rmse is None or reference is None or not math.isfinite(rmse) or not reference > 0:
        return None
    return {
        "lobe": name,
        "about": dict(LOBES)[name],
        "sigma": sigma,
        "max_F_tilde": _largest(F_tilde),
        "heldout_rgb_rmse": rmse,
        "lambertian_same_light_rgb_rmse": reference,
        "ratio": rmse / reference,
        "status": status,
    }


def lobes_judged(summary: dict) -> dict:
    """The lobes judged in an evaluation's JSON (`Evaluation.to_json()`): one row each
    (`lobe`, `about`, `sigma`, `max_F_tilde`, held-out RGB RMSE in levels, Lambert's under
    the same light, their `ratio`, the lobe's `status`), and `best_determined`: the lobe of
    lowest ratio among those whose status is `successful` and that predict better than
    Lambert's (ratio under 1; None where none does). Every row
    is judged on the same test frames; the facet rows' reference is Lambert's on their own
    views (the same tracked points under the map)."""
    fitted = summary.get("models", {}).get("cook_torrance", {})
    # Lambert's under Cook-Torrance's light; where that light is at the camera, Lambert's own.
    reference = summary.get("lambertian_same_light_rgb_rmse_test")
    if reference is None and fitted.get("light") == "ColocatedLight":
        reference = summary.get("lambertian_rgb_rmse_test")
    rows = [
        _row(
            "normals",
            fitted.get("sigma"),
            fitted.get("F_tilde"),
            summary.get("cook_torrance_rgb_rmse_test"),
            reference,
            fitted.get("status"),
        )
    ]
    facets = summary.get("facets") or {}
    for name, block in (
        ("facets", facets),
        ("facets_at_the_marginal_width", facets.get("facets_at_the_marginal_width") or {}),
    ):
        if "heldout_rgb_rmse" in block:
            rows.append(
                _row(
                    name,
                    block.get("sigma"),
                    block.get("F_tilde"),
                    block["heldout_rgb_rmse"],
                    block.get("lambertian_same_light_rgb_rmse"),
                    block.get("status"),
                )
            )
            if rows[-1] is not None and block.get("effects_undone"):
                rows[-1]["effects_undone"] = block["effects_undone"]
    rows = [row for row in rows if row is not None]
    determined = [row for row in rows if row["status"] == "successful" and row["ratio"] < 1]
    best = min(determined, key=lambda row: row["ratio"])["lobe"] if determined else None
    return {
        "lobes": rows,
        "best_determined": best,
        "note": (
            "held-out RGB RMSE (8-bit levels) of Cook-Torrance with each lobe, and its ratio "
            "to Lambert's model under the same light on the same views; best_determined: the "
            "lowest ratio under 1 among the lobes whose status is successful (the data "
            "determine them); effects_undone: a row judged on the views with the model's image "
            "effects undone (its levels the radiance's, the first frame's exposure: compare "
            "its ratio)"
        ),
    }


def _undone(row: dict) -> str:
    effects = row.get("effects_undone")
    return f" (levels with {' and '.join(effects)} undone)" if effects else ""


def lobes_judged_lines(block: dict) -> list[str]:
    """The command's lines for `lobes_judged`'s block."""
    lines = ["the lobes judged on the test frames (RGB RMSE, levels; x Lambert's, same light):"]
    for row in block["lobes"]:
        sigma = row["sigma"]
        sigma = f"{sigma:.3g}" if isinstance(sigma, int | float) else str(sigma)
        F_tilde = row["max_F_tilde"]
        lines.append(
            f"  about {row['about']}: sigma {sigma}, max F_tilde "
            f"{'-' if F_tilde is None else f'{F_tilde:.3g}'}: {row['heldout_rgb_rmse']:.2f} "
            f"against {row['lambertian_same_light_rgb_rmse']:.2f}"
            + _undone(row)
            + f", {row['ratio']:.3f}x, {row['status']}"
        )
    best = block["best_determined"]
    best = "none beats Lambert's with status successful" if best is None else dict(LOBES)[best]
    lines.append(f"  the lowest ratio among the determined lobes: {best}")
    return lines
