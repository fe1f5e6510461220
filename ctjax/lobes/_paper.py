from .._typing import RGBLike, ScalarLike
from ._beckmann import Beckmann
from ._lambertian import Lambertian
from ._lobe import BRDF
from ._specular import Specular


def cook_torrance_brdf(rho_tilde: RGBLike, F_tilde: RGBLike, sigma: ScalarLike) -> BRDF:
    """The paper's model, eq. (1)-(2): Lambertian + Beckmann specular with constant F."""
    return BRDF(Lambertian(rho_tilde), Specular(F_tilde, Beckmann(sigma)))
