"""Riccati equations of the Kalman and Lainiotis filters and their steady state."""

from ._checks import check_detectable, check_stabilisable
from ._lyapunov import power_sum
from ._lainiotis import LainiotisParameters, lainiotis_parameters
from ._solvers import METHODS, SteadyState, riccati_residual, riccati_step, steady_state

__all__ = [
    "METHODS",
    "SteadyState",
    "steady_state",
    "riccati_step",
    "riccati_residual",
    "lainiotis_parameters",
    "LainiotisParameters",
    "check_detectable",
    "check_stabilisable",
    "power_sum",
]
