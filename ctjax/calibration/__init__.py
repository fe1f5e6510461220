"""Light calibration: the laparoscope's light from images (paper section 5, and beyond)."""

from ..solvers import ClosedFormLM as ClosedFormLM
from ..solvers import least_squares as least_squares
from ._field_problem import PixelProblem as PixelProblem
from ._field_problem import PixelSolution as PixelSolution
from ._field_problem import directions_from_paper_angles as directions_from_paper_angles
from ._field_problem import paper_angles as paper_angles
from ._field_problem import pixel_residuals as pixel_residuals
from ._field_problem import solve_pixels as solve_pixels
from ._light_field import FIELD_SOLVER as FIELD_SOLVER
from ._light_field import calibrate_light_field as calibrate_light_field
from ._near_light import calibrate_near_light as calibrate_near_light
from ._near_light_models import falloff_choices as falloff_choices
from ._near_light_models import named_falloff as named_falloff
from ._spline import fit_spline as fit_spline
