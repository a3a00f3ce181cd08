"""Fuzzy inference: membership functions and zero-order Takagi–Sugeno systems."""

from ._anfis import AnfisResult, anfis_train
from ._combination import fused_covariance_prop3, fused_covariance_trace, probabilistic_fusion
from ._membership import MembershipFunction, gaussian, trapezoidal, triangular, uniform_partition
from ._ts import TakagiSugeno

__all__ = [
    "AnfisResult",
    "anfis_train",
    "fused_covariance_prop3",
    "fused_covariance_trace",
    "probabilistic_fusion",
    "MembershipFunction",
    "TakagiSugeno",
    "gaussian",
    "trapezoidal",
    "triangular",
    "uniform_partition",
]
