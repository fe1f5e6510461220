"""Estimation: specular set and ring, closed-form NNLS, the BnB over the nonlinear
parameters, and the BRDF fit (paper sections 4 and 6)."""

from ._albedo_map import fit_brdf_map as fit_brdf_map
from ._branch_and_bound import GridSearchResult as GridSearchResult
from ._branch_and_bound import grid_search as grid_search
from ._brdf import LAMBERTIAN as LAMBERTIAN
from ._brdf import PAPER as PAPER
from ._brdf import TWO_SCALES as TWO_SCALES
from ._brdf import BRDFFamily as BRDFFamily
from ._brdf import BRDFFit as BRDFFit
from ._brdf import design_columns as design_columns
from ._brdf import design_geometry as design_geometry
from ._brdf import design_matrix as design_matrix
from ._brdf import fit_brdf as fit_brdf
from ._capture_fit import ALBEDO_CHOICES as ALBEDO_CHOICES
from ._capture_fit import MaskOptions as MaskOptions
from ._capture_fit import capture_sets as capture_sets
from ._capture_fit import default_albedo as default_albedo
from ._capture_fit import fit_capture as fit_capture
from ._closed_form import nnls as nnls
from ._closed_form import nnls_columns as nnls_columns
from ._closed_form import nnls_normal_equations as nnls_normal_equations
from ._dense_maps import albedo_maps as albedo_maps
from ._highlights import HighlightRule as HighlightRule
from ._highlights import HLSThresholds as HLSThresholds
from ._highlights import WhiterThanTissue as WhiterThanTissue
from ._projection import project_weights as project_weights
from ._samples import ShadingSamples as ShadingSamples
from ._samples import colocated_samples as colocated_samples
from ._samples import paper_coefficients as paper_coefficients
from ._specular_set import SpecularSets as SpecularSets
from ._specular_set import specular_mask as specular_mask
from ._specular_set import specular_sets as specular_sets
