"""The general fitter: any BRDF + light + effects fitted to measurements."""

from .._model import ShadingModel as ShadingModel
from .._model import paper_model as paper_model
from .._result import Estimate as Estimate
from ..observations import PixelSamples as PixelSamples
from ..observations import capture_samples as capture_samples
from ._fit import LEVENBERG_MARQUARDT as LEVENBERG_MARQUARDT
from ._fit import fit_model as fit_model
from ._fit import pixel_columns as pixel_columns
from ._fit import pixel_predict as pixel_predict
from ._fit import predictions as predictions
from ._fit import rmse_levels as rmse_levels
from ._fit import roughness_variants as roughness_variants
from ._map_least_squares import TrackSamples as TrackSamples
from ._map_least_squares import fit_model_map as fit_model_map
from ._map_least_squares import lobe_gain_where_it_shows as lobe_gain_where_it_shows
from ._map_least_squares import map_standard_errors as map_standard_errors
from ._measured import DirectionSamples as DirectionSamples
from ._measured import brdf_columns as brdf_columns
from ._measured import brdf_predict as brdf_predict
from ._measured import measured_samples as measured_samples
from ._parameters import Parameter as Parameter
from ._parameters import constrained as constrained
from ._parameters import free_parameters as free_parameters
from ._parameters import strongly_typed as strongly_typed
from ._parameters import unconstrained as unconstrained
