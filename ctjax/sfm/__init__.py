"""Shape from rigid structure-from-motion (paper section 6, step 1): pycolmap's sparse points
and poses, then a dense smooth surface with depth and normals at every covered pixel."""

from ._colmap import SparseModel as SparseModel
from ._colmap import sparse_reconstruction as sparse_reconstruction
from ._reconstruct import Reconstruction as Reconstruction
from ._reconstruct import ViewSurface as ViewSurface
from ._reconstruct import reconstruct as reconstruct
from ._reconstruct import reconstruct_capture as reconstruct_capture
from ._reconstruct import with_reconstructed_shape as with_reconstructed_shape
from ._surface import DepthSurface as DepthSurface
from ._surface import fit_depth_surface as fit_depth_surface
