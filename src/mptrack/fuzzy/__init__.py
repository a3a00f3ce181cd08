"""Fuzzy inference: membership functions and zero-order Takagi–Sugeno systems."""

from ._anfis import AnfisResult, anfis_train
from ._membership import MembershipFunction, gaussian, trapezoidal, triangular, uniform_partition
from ._ts import TakagiSugeno

__all__ = [
    "AnfisResult",
    "anfis_train",
    "MembershipFunction",
    "TakagiSugeno",
    "gaussian",
    "trapezoidal",
    "triangular",
    "uniform_partition",
]
