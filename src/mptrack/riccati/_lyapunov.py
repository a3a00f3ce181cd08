"""Powers and finite Lyapunov sums of a transition matrix by repeated squaring."""

from __future__ import annotations

import numpy as np

__all__ = ["power_sum"]


def power_sum(F: np.ndarray, Q: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """(F^N, S_N) with S_N = sum_{j<N} F^j Q F^{j T}, in O(log N) matrix products.

    Doubling: (F^{2j}, S_{2j}) = (F^j F^j, S_j + F^j S_j F^{j T}); one step more:
    (F^{j+1}, S_{j+1}) = (F F^j, Q + F S_j F^T).  An overflow gives infinities (the caller's
    finiteness check reports it); a stable F gives S_N -> the Lyapunov solution.
    """
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
