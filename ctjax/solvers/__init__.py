"""Least-squares solvers as objects, passed to the estimators that take `solver=`: any
optimistix least-squares solver, or these two written for ctjax's problems."""

from ._closed_form_lm import ClosedFormLM as ClosedFormLM
from ._dense_lm import DenseLM as DenseLM
from ._dense_lm import JacobianBlocks as JacobianBlocks
from ._least_squares import Solver as Solver
from ._least_squares import least_squares as least_squares
