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
    """F^N and S_N = sum_{j<N} F^j Q F^jT in O(log N) matrix products.

    Doubling: (F^2j, S_2j) = (F^j F^j, S_j + F^j S_j F^jT); one step more:
    (F^(j+1), S_(j+1)) = (F F^j, Q + F S_j F^T).  A stable F gives S_N -> the Lyapunov solution.

    Parameters
    ----------
    F : array_like, shape (n, n)
        Transition matrix.
    Q : array_like, shape (n, n)
        A covariance.
    N : int
        The power, >= 0.

    Returns
    -------
    F_N, S_N : ndarray, shape (n, n)

    Raises
    ------
    NonFiniteError
        An overflow; the message names the input of largest magnitude.
    """
    F = as_matrix("F", F)
    if F.shape[0] != F.shape[1]:
        raise ShapeError(f"F: expected a square matrix, got shape {F.shape}")
    Q = check_covariance("Q", Q, F.shape[0])
    return power_sum_unchecked(F, Q, check_int("N", N, minimum=0))
