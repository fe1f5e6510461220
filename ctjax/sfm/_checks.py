"""What `reconstruct` accepts, checked before any work: the sizes it is given, the texture
refinement's weight and the dense surfaces' knot spacing, each error naming the argument as
the Python API and the command line call it."""

import math

from .._camera import Camera
from .._errors import ParameterError
from ._surface import MAX_SURFACE_COEFFICIENTS, surface_coefficients

# The sizes a capture may be given, and the texture refinement's penalty weight: wide ranges
# (a micrometre to a kilometre of median depth) that keep every solve finite. 1e300 mm
# overflowed the refinement's weights; 1e-200 mm wrote depth maps of NaN.
SIZE_RANGES = {
    "scale_mm (--scale-mm)": (1e-3, 1e6),
    "volume_mm3 (--volume-mm3)": (1e-9, 1e18),
    "texture_smoothing (--texture-smoothing)": (1e-6, 1e6),
}


def check_scale(scale_mm, volume_mm3, knot_spacing_px=None, texture_smoothing=None) -> None:
    if scale_mm is not None and volume_mm3 is not None:
        raise ParameterError("give scale_mm (--scale-mm) or volume_mm3 (--volume-mm3), not both")
    # Each named as the Python API and the command line call it.
    given = (
        ("scale_mm (--scale-mm)", scale_mm),
        ("volume_mm3 (--volume-mm3)", volume_mm3),
        ("knot_spacing_px (--knot-px)", knot_spacing_px),
        ("texture_smoothing (--texture-smoothing)", texture_smoothing),
    )
    for name, value in given:
        if value is None:
            continue
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f"{name} must be a positive finite number, got {value}")
        low, high = SIZE_RANGES.get(name, (0, math.inf))
        if not low <= value <= high:
            raise ParameterError(f"{name} must be in [{low:g}, {high:g}], got {value:g}")


def check_knots(camera: Camera, knot_spacing_px: float) -> None:
    """The dense surfaces' systems are dense matrices over the spline's coefficients: a knot
    spacing that gives more than `MAX_SURFACE_COEFFICIENTS` over the image is refused up
    front, naming the finest spacing this image allows (0.1 px on 96x80 asked for 4 TiB)."""
    count = surface_coefficients(camera.width, camera.height, knot_spacing_px)
    if count > MAX_SURFACE_COEFFICIENTS:
        finest = knot_spacing_px
        while surface_coefficients(camera.width, camera.height, finest) > MAX_SURFACE_COEFFICIENTS:
            finest *= 1.05
        raise ParameterError(
            f"knot_spacing_px (--knot-px) {knot_spacing_px:g} gives {count} spline coefficients "
            f"over the {camera.width}x{camera.height} image, more than the "
            f"{MAX_SURFACE_COEFFICIENTS} the dense surfaces solve for: give at least "
            f"{math.ceil(finest)} px"
        )
