"""Van Loan's exact discretisation of a continuous-time linear model, of validated arguments: the core
of :func:`mptrack.models.van_loan`, :func:`mptrack.models.discretize` and
:func:`mptrack.models.discretize_intervals`, shared with the irregular-time filters of mptrack.linear and
the gated tracker of mptrack.tracking, which validate their own arguments and name them in errors."""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ..errors import ParameterError

__all__ = ["van_loan_unchecked", "intervals_unchecked"]


def van_loan_unchecked(Phi: np.ndarray, LQL: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) from Phi and L Qc L^T for one dt, without validation."""
    n = Phi.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -Phi
    M[:n, n:] = LQL
    M[n:, n:] = Phi.T
    with np.errstate(over="ignore", invalid="ignore"):
        E = scipy.linalg.expm(M * dt)
        F = np.ascontiguousarray(E[n:, n:].T)
        Q = F @ E[:n, n:]
    if not (np.all(np.isfinite(F)) and np.all(np.isfinite(Q))):
        raise ParameterError(f"dt: {dt!r} s is too long for this model; e^(Phi dt) or Q overflows float64")
    return F, 0.5 * (Q + Q.T)


def intervals_unchecked(model, dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) stacks (T, n, n) of a ContinuousLinearModel ``model`` over validated intervals ``dts`` (T,) (an interval too long for float64 may give
    infinities, or a ParameterError naming dt: the callers name their own argument)."""
    n = model.n
    if dts.size == 0:
        return np.empty((0, n, n)), np.empty((0, n, n))
    LQL = model.L @ model.Qc @ model.L.T
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -model.Phi
    M[:n, n:] = LQL
    M[n:, n:] = model.Phi.T
    powers = [np.eye(2 * n)]
    for _ in range(2 * n):
        powers.append(powers[-1] @ M)
    if not np.any(powers[-1]):
        factorial = np.cumprod(np.r_[1.0, np.arange(1, 2 * n)])
        with np.errstate(over="ignore", invalid="ignore"):
            coef = dts[:, None] ** np.arange(2 * n) / factorial  # (T, 2n)
            E = np.einsum("tj,jab->tab", coef, np.stack(powers[:-1]))
            F = np.ascontiguousarray(E[:, n:, n:].transpose(0, 2, 1))
            Q = F @ E[:, :n, n:]
    else:
        values, index = np.unique(dts, return_inverse=True)
        pairs = [van_loan_unchecked(model.Phi, LQL, float(dt)) for dt in values]
        F = np.stack([f for f, _ in pairs])[index]
        Q = np.stack([q for _, q in pairs])[index]
    return F, 0.5 * Q + 0.5 * Q.transpose(0, 2, 1)      # no overflow of the sum near the float maximum
