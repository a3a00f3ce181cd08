"""The coefficients A^j B of the FIR steady-state filter (Assimakis & Adam 2014, eq. 22), of validated
arguments: the core of :func:`mptrack.linear.fir_coefficients`, shared by the FIR filters of
mptrack.linear and mptrack.batch."""

from __future__ import annotations

import numpy as np

__all__ = ["coefficients_unchecked"]


def coefficients_unchecked(A: np.ndarray, B: np.ndarray, M: int) -> np.ndarray:
    """:func:`mptrack.linear.fir_coefficients` of validated arguments: C (M, n, m) with C[j] = A^j B."""
    C = np.empty((M,) + np.shape(B))
    C[0] = B
    for j in range(1, M):
        C[j] = A @ C[j - 1]
    return C
