"""Baselines users benchmark against (optional dependencies: `pip install ctjax[baseline]`)."""

from ._socp import SOCPResult as SOCPResult
from ._socp import socp_branch_and_bound as socp_branch_and_bound
