"""Model diagnostics: compare the model with measurements, see where it fails, learn which
physical effect is missing."""

from .._residuals import residual_map as residual_map
from ._budget import ResidualBudget as ResidualBudget
from ._budget import heldout_budget as heldout_budget
from ._budget import residual_budget as residual_budget
from ._candidates import CANDIDATES as CANDIDATES
from ._candidates import AbstractCandidate as AbstractCandidate
from ._candidates import candidate as candidate
from ._candidates import discover_candidates as discover_candidates
from ._diagnose import diagnose as diagnose
from ._diagnosis import Diagnosis as Diagnosis
from ._loop import DiagnosisLoop as DiagnosisLoop
from ._loop import diagnose_loop as diagnose_loop
from ._loop import plot_loop as plot_loop
from ._plots import diagnosis_plots as diagnosis_plots
from ._variables import VARIABLES as VARIABLES
from ._variables import binned as binned
from ._variables import physical_variables as physical_variables
