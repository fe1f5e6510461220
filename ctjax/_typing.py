"""jaxtyping aliases used across ctjax (named dimensions, one place)."""

from jaxtyping import Array, ArrayLike, Bool, Float, Int, PyTree, Real

Scalar = Float[Array, ""]
ScalarLike = Real[ArrayLike, ""] | float
RGB = Float[Array, "3"]
RGBLike = Real[ArrayLike, "3"]
Pixel = tuple[Float[Array, ""], Float[Array, ""]]  # (u, v)

__all__ = [
    "RGB",
    "Array",
    "ArrayLike",
    "Bool",
    "Float",
    "Int",
    "Pixel",
    "PyTree",
    "RGBLike",
    "Real",
    "Scalar",
    "ScalarLike",
]
