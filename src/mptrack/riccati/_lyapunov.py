"""Powers and finite Lyapunov sums of a transition matrix by repeated squaring."""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result
from .._core.lyapunov import power_sum_unchecked
from .._core.validation import as_matrix, check_covariance, check_int
from ..errors import ShapeError

__all__ = ["power_sum"]


@finite_result("F^N and its Lyapunov sum")
def power_sum(F, Q, N: int) -> tuple[np.ndarray, np.ndarray]:
    """(F^N, S_N) with S_N = sum_{j<N} F^j Q F^{j T}, in O(log N) matrix products.

    F (n, n), Q (n, n) a covariance, N >= 0.  Doubling: (F^{2j}, S_{2j}) = (F^j F^j, S_j + F^j S_j F^{j T});
    one step more: (F^{j+1}, S_{j+1}) = (F F^j, Q + F S_j F^T).  A stable F gives S_N -> the Lyapunov
    solution; an overflow is a NonFiniteError naming the input of largest magnitude.
    """
    F = as_matrix("F", F)
    if F.shape[0] != F.shape[1]:
        raise ShapeError(f"F: expected a square matrix, got shape {F.shape}")
    Q = check_covariance("Q", Q, F.shape[0])
    return power_sum_unchecked(F, Q, check_int("N", N, minimum=0))
