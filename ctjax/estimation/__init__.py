"""Estimation: closed-form NNLS, the BnB over the nonlinear
parameters, and the BRDF fit (paper sections 4 and 6)."""

# The specular set and ring live below the observations (`ctjax.specular`); named here too.
from ..specular import HighlightRule as HighlightRule
from ..specular import HLSThresholds as HLSThresholds
from ..specular import MaskOptions as MaskOptions
from ..specular import SpecularSets as SpecularSets
from ..specular import WhiterThanTissue as WhiterThanTissue
from ..specular import capture_sets as capture_sets
from ..specular import specular_mask as specular_mask
from ..specular import specular_sets as specular_sets
from ._branch_and_bound import GridSearchResult as GridSearchResult
from ._branch_and_bound import grid_search as grid_search
from ._branch_and_bound_map import fit_brdf_map as fit_brdf_map
from ._brdf import LAMBERTIAN as LAMBERTIAN
from ._brdf import PAPER as PAPER
from ._brdf import TWO_SCALES as TWO_SCALES
from ._brdf import BRDFFamily as BRDFFamily
from ._brdf import BRDFFit as BRDFFit
from ._brdf import design_columns as design_columns
from ._brdf import design_geometry as design_geometry
from ._brdf import design_matrix as design_matrix
from ._brdf import diffuse_alone as diffuse_alone
from ._brdf import fit_brdf as fit_brdf
from ._brdf import with_diffuse as with_diffuse
from ._capture_fit import ALBEDO_CHOICES as ALBEDO_CHOICES
from ._capture_fit import default_albedo as default_albedo
from ._capture_fit import fit_capture as fit_capture
from ._capture_fit import why_no_albedo_map as why_no_albedo_map
from ._closed_form import nnls as nnls
from ._closed_form import nnls_columns as nnls_columns
from ._closed_form import nnls_normal_equations as nnls_normal_equations
from ._dense_maps import albedo_maps as albedo_maps
from ._samples import ShadingSamples as ShadingSamples
from ._samples import colocated_samples as colocated_samples
from ._samples import paper_coefficients as paper_coefficients
from ._variable_projection import project_weights as project_weights
