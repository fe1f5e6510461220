"""Reflectance as composable lobes: a BRDF is a sum of lobes, each with a linear weight."""

from ._beckmann import Beckmann as Beckmann
from ._cook_torrance import CookTorrance as CookTorrance
from ._diffuse import diffuse_lobe_named as diffuse_lobe_named
from ._diffuse import diffuse_lobes as diffuse_lobes
from ._distribution import AbstractDistribution as AbstractDistribution
from ._factor import AbstractSpecularFactor as AbstractSpecularFactor
from ._geometric_attenuation import GeometricAttenuation as GeometricAttenuation
from ._ggx import GGX as GGX
from ._lambertian import Lambertian as Lambertian
from ._lobe import BRDF as BRDF
from ._lobe import AbstractLobe as AbstractLobe
from ._multiscale import MultiScaleBeckmann as MultiScaleBeckmann
from ._paper import cook_torrance_brdf as cook_torrance_brdf
from ._schlick import SchlickFresnel as SchlickFresnel
from ._specular import Specular as Specular
