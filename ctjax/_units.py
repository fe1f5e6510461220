"""The length unit of a capture, and JSON written in it.

Depth in a capture folder is in millimetres, unless the shape was reconstructed without a
known size (`ctjax reconstruct` without `--scale-mm` or `--volume-mm3`): lengths are then in
units of the median depth of the reference frame (`RELATIVE`). Every JSON with a length says
which (`"length_unit"`), and in a relative unit no key ends in `_mm`: `offset_mm` becomes
`offset`, `sfs_error_mm` becomes `sfs_error`.
"""

METRIC = "mm"
RELATIVE = "median_depth"


def length_unit_of(capture) -> str:
    """The length unit of a `Capture` or of its `Observations`."""
    return getattr(getattr(capture, "capture", capture), "length_unit", METRIC)


def unit_of_reconstruction(report: dict) -> str:
    """`"mm"` when a reconstruction report (`reconstruction.json`) says it is metric."""
    return METRIC if report.get("scale", {}).get("metric", False) else RELATIVE


def in_length_unit(data, unit: str):
    """`data` (a JSON tree) with `"length_unit"` added at its top, and in a relative unit
    every key ending in `_mm` renamed without it (at every depth)."""
    if unit == METRIC:
        return {"length_unit": unit, **data} if isinstance(data, dict) else data
    renamed = _renamed(data)
    return {"length_unit": unit, **renamed} if isinstance(renamed, dict) else renamed


def _renamed(data):
    if isinstance(data, dict):
        return {_key(key): _renamed(value) for key, value in data.items()}
    if isinstance(data, list | tuple):
        return [_renamed(value) for value in data]
    return data


def _key(key):
    if isinstance(key, str) and key.endswith("_mm"):
        return key.removesuffix("_mm")
    if isinstance(key, str) and "_mm_" in key:  # e.g. "offset_mm_stderr"
        return key.replace("_mm_", "_")
    return key


def label(unit: str) -> str:
    """The unit as printed: "mm", or "median depths"."""
    return "mm" if unit == METRIC else "median depths (up to scale)"
