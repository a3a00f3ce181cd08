"""F^N and the finite Lyapunov sum S_N = sum_{j<N} F^j Q F^{j T} by repeated squaring, of validated
arguments: the core of :func:`mptrack.riccati.power_sum`, shared with the N-step prediction of
mptrack.linear, which validates its own arguments and names them in errors."""

from __future__ import annotations

import numpy as np

__all__ = ["power_sum_unchecked"]


def power_sum_unchecked(F: np.ndarray, Q: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`mptrack.riccati.power_sum` of validated arguments; an overflow gives infinities (the caller's
    finiteness check names its own argument)."""
    n = F.shape[0]
    power, total = np.eye(n), np.zeros((n, n))
    with np.errstate(all="ignore"):
        for bit in bin(int(N))[2:]:
            total = total + power @ total @ power.T
            power = power @ power
            if bit == "1":
                total = Q + F @ total @ F.T
                power = F @ power
    return power, 0.5 * (total + total.T)
