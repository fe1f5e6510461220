"""The specular set S and its ring S~ (paper section 4, step 2): which pixels are
highlights (`WhiterThanTissue`, the paper's `HLSThresholds`), the sets of one image
(`specular_sets`) and of every frame of a capture (`capture_sets`); sigma from the density of
the highlights over the half angle (`sparkle_density`); whether the highlights' peaks sit
at N = H, or one rotation of the normals puts them there (`highlight_alignment`); whether
they stay on the tissue from frame to frame (`highlight_persistence`). Below the
observations and the estimators, which both use them."""

from ._capture_sets import MaskOptions as MaskOptions
from ._capture_sets import capture_sets as capture_sets
from ._highlight_alignment import HighlightAlignment as HighlightAlignment
from ._highlight_alignment import HighlightPeaks as HighlightPeaks
from ._highlight_alignment import flag_misoriented as flag_misoriented
from ._highlight_alignment import highlight_alignment as highlight_alignment
from ._highlight_alignment import highlight_alignment_line as highlight_alignment_line
from ._highlight_alignment import highlight_alignment_summary as highlight_alignment_summary
from ._highlight_alignment import highlight_peaks as highlight_peaks
from ._highlights import HighlightRule as HighlightRule
from ._highlights import HLSThresholds as HLSThresholds
from ._highlights import WhiterThanTissue as WhiterThanTissue
from ._persistence import HighlightPersistence as HighlightPersistence
from ._persistence import highlight_persistence as highlight_persistence
from ._sparkle_density import SparkleDensity as SparkleDensity
from ._sparkle_density import sparkle_density as sparkle_density
from ._sparkle_density import sparkle_density_line as sparkle_density_line
from ._sparkle_density import sparkle_density_of_angles as sparkle_density_of_angles
from ._sparkle_density import sparkle_density_summary as sparkle_density_summary
from ._specular_set import DEFAULT_MIN_SPECK_PX as DEFAULT_MIN_SPECK_PX
from ._specular_set import DEFAULT_RING_PX as DEFAULT_RING_PX
from ._specular_set import SpecularSets as SpecularSets
from ._specular_set import specular_mask as specular_mask
from ._specular_set import specular_sets as specular_sets
