"""ctjax: differentiable Cook-Torrance rendering and in-vivo reflectance estimation in JAX.

Malti & Bartoli, "Estimating the Cook-Torrance BRDF Parameters In-Vivo from Laparoscopic
Images" (AE-CAI 2012), as a composable, jitted, vmapped library.
"""

from . import effects as effects
from . import lights as lights
from . import lobes as lobes
from ._camera import Camera as Camera
from ._convert import FIXED as FIXED
from ._convert import PER_FRAME as PER_FRAME
from ._convert import POSITIVE as POSITIVE
from ._convert import UNIT_INTERVAL as UNIT_INTERVAL
from ._convert import domain as domain
from ._convert import named as named
from ._errors import CaptureError as CaptureError
from ._errors import CtjaxError as CtjaxError
from ._errors import ParameterError as ParameterError
from ._errors import ReconstructionError as ReconstructionError
from ._json import named_parameters as named_parameters
from ._json import to_json as to_json
from ._model import ShadingModel as ShadingModel
from ._model import paper_model as paper_model
from ._performance import tune_malloc as tune_malloc
from ._performance import tune_xla as tune_xla
from ._render import apply_effects as apply_effects
from ._render import map_pixels as map_pixels
from ._render import render as render
from ._render import render_columns as render_columns
from ._render import shade as shade
from ._render import shade_columns as shade_columns
from ._result import Estimate as Estimate
from ._status import Status as Status
from ._vector import Vec3 as Vec3
from .effects import Ambient as Ambient
from .effects import CameraGamma as CameraGamma
from .effects import SRGBResponse as SRGBResponse
from .lights import ColocatedLight as ColocatedLight
from .lights import InverseSquare as InverseSquare
from .lights import LensPlaneLight as LensPlaneLight
from .lights import LightField as LightField
from .lights import PointLight as PointLight
from .lights import SpotFalloff as SpotFalloff
from .lobes import BRDF as BRDF
from .lobes import GGX as GGX
from .lobes import Beckmann as Beckmann
from .lobes import CookTorrance as CookTorrance
from .lobes import GeometricAttenuation as GeometricAttenuation
from .lobes import Lambertian as Lambertian
from .lobes import MultiScaleBeckmann as MultiScaleBeckmann
from .lobes import SchlickFresnel as SchlickFresnel
from .lobes import Specular as Specular
from .lobes import cook_torrance_brdf as cook_torrance_brdf
from .observations import Observations as Observations

__version__ = "0.1.0"
