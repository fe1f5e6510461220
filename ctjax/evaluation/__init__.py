"""Evaluation as in the paper (section 7): RGB error and shape from shading, Lambertian
against Cook-Torrance."""

from ._evaluate import evaluate as evaluate
from ._evaluate import fit_colocated as fit_colocated
from ._evaluate import fit_lambertian as fit_lambertian
from ._evaluation import Evaluation as Evaluation
from ._integrate import integrate_gradients as integrate_gradients
from ._lobes import lobes_judged as lobes_judged
from ._lobes import lobes_judged_lines as lobes_judged_lines
from ._plots import evaluation_plots as evaluation_plots
from ._refine import NormalRefinement as NormalRefinement
from ._refine import refine_normals as refine_normals
from ._scale import bounding_box_volume as bounding_box_volume
from ._scale import scale_to_volume as scale_to_volume
from ._sfs import ShapeFromShading as ShapeFromShading
from ._sfs import sfs_cook_torrance as sfs_cook_torrance
from ._sfs import sfs_refined as sfs_refined
from ._sfs import sfs_tsai_shah as sfs_tsai_shah
from ._tsai_shah import solve_log_depth as solve_log_depth
from ._tsai_shah import tsai_shah as tsai_shah
