"""The coefficients A^j B of the FIR steady-state filter (Assimakis & Adam 2014, eq. 22), of validated
arguments: the core of :func:`mptrack.linear.fir_coefficients`, shared by the FIR filters of
mptrack.linear and mptrack.batch; and the check of the order rule's arguments (eps, norm) they share
with :func:`mptrack.linear.fir_order`."""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from .validation import check_positive

__all__ = ["coefficients_unchecked", "check_order_rule", "NORMS"]

#: the matrix norms of the order rule ||A^M|| < eps (numpy.linalg.norm's matrix orders)
NORMS = (2, -2, 1, -1, np.inf, -np.inf, "fro", "nuc")


def check_order_rule(eps, norm) -> float:
    """``eps`` (a finite number > 0) and ``norm`` (one of NORMS) of the rule ||A^M|| < eps; returns eps.
    Checked even when the caller gives the order M, so a bad eps is never accepted unread."""
    if norm not in NORMS:
        raise ParameterError(f"norm: expected one of {NORMS}, got {norm!r}")
    return check_positive("eps", eps)


def coefficients_unchecked(A: np.ndarray, B: np.ndarray, M: int) -> np.ndarray:
    """:func:`mptrack.linear.fir_coefficients` of validated arguments: C (M, n, m) with C[j] = A^j B."""
    C = np.empty((M,) + np.shape(B))
    C[0] = B
    for j in range(1, M):
        C[j] = A @ C[j - 1]
    return C
