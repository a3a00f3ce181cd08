"""Fuzzy inference: membership functions and zero-order Takagi–Sugeno systems."""

from ._membership import MembershipFunction, gaussian, trapezoidal, triangular, uniform_partition
from ._ts import TakagiSugeno

__all__ = [
    "MembershipFunction",
    "TakagiSugeno",
    "gaussian",
    "trapezoidal",
    "triangular",
    "uniform_partition",
]
