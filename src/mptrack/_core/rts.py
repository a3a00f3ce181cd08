"""The Rauch-Tung-Striebel backward pass (Rauch, Tung & Striebel 1965), compiled: shared by the
smoothers of mptrack.linear (fixed and per-step F, Q), mptrack.nonlinear (EKF/UKF smoothers, through
the cross-covariances) and the gated tracker of mptrack.tracking.  The recursion is in the docstring of
mptrack/linear/_smoother.py; the callers validate their arguments.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from ..result import FilterResult

__all__ = ["rts_backward", "rts_backward_linear", "smoother_gains"]


def smoother_gains(PFt: np.ndarray, P_pred: np.ndarray) -> np.ndarray:
    """C = P_filt F^T P_pred^{-1} from PFt = P_filt F^T, for a stack (T, n, n) or one (n, n).

    One batched solve when every P_pred is positive definite (Cholesky succeeds);
    otherwise, per matrix, a pseudo-inverse where P_pred is singular (zero prior,
    rank-deficient Q).
    """
    try:
        np.linalg.cholesky(P_pred)
        return np.swapaxes(np.linalg.solve(P_pred, np.swapaxes(PFt, -1, -2)), -1, -2)
    except np.linalg.LinAlgError:
        if P_pred.ndim == 2:
            return PFt @ np.linalg.pinv(P_pred, hermitian=True)
        return np.stack([smoother_gains(a, b) for a, b in zip(PFt, P_pred)])


def rts_backward_linear(result: FilterResult, F: np.ndarray, Q: np.ndarray) -> FilterResult:
    """The RTS backward pass; F, Q are one (n, n) pair or per-step stacks (T-1, n, n)
    where F[k], Q[k] take x(k) to x(k+1) (row k = time k+1 of the result)."""
    x_filt = np.asarray(result.x, dtype=float)
    P_filt = np.asarray(result.P, dtype=float)
    Ft = np.swapaxes(F, -1, -2)
    # off the backward loop: x(k+1/k), P(k+1/k) and the gains C(k) for k = 1..T-1
    x_pred = (F @ x_filt[:-1, :, None])[..., 0]
    PFt = P_filt[:-1] @ Ft
    P_pred = F @ PFt + Q
    P_pred = 0.5 * (P_pred + np.swapaxes(P_pred, -1, -2))
    C = smoother_gains(PFt, P_pred)
    xs = np.empty_like(x_filt)
    Ps = np.empty_like(P_filt)
    c = np.ascontiguousarray
    _rts_loop(c(x_filt), c(P_filt), c(x_pred), c(P_pred), c(C), xs, Ps)
    return FilterResult(x=xs, P=Ps, method="RTS")


def rts_backward(x_filt, P_filt, x_pred, P_pred, cross, *, gains: bool = False):
    """The RTS backward pass from filtered x(k/k), P(k/k) (K, n), (K, n, n), the predictions
    x(k+1/k), P(k+1/k) and the cross-covariances cross[k] = Cov(x(k), x(k+1) | k) (K-1 each):
    C(k) = cross[k] P(k+1/k)^-1 (P(k/k) F^T for a linear model).  Returns (x(k/K), P(k/K)), and the
    gains C (K-1, n, n) with ``gains=True`` (the lag-one smoothed covariances are
    Cov(x(k+1), x(k) | K) = P(k+1/K) C(k)^T, which EM needs)."""
    c = np.ascontiguousarray
    P_pred = np.asarray(P_pred, dtype=float)
    P_pred = 0.5 * (P_pred + np.swapaxes(P_pred, -1, -2))
    C = smoother_gains(np.asarray(cross, dtype=float), P_pred)
    xs, Ps = np.empty_like(x_filt, dtype=float), np.empty_like(P_filt, dtype=float)
    _rts_loop(c(x_filt, dtype=float), c(P_filt, dtype=float), c(x_pred, dtype=float), c(P_pred), c(C), xs, Ps)
    return (xs, Ps, C) if gains else (xs, Ps)


@njit(cache=True)
def _rts_loop(x_filt, P_filt, x_pred, P_pred, C, xs, Ps):  # pragma: no cover - compiled
    """The backward recursion of the module docstring, compiled; row k of x_pred, P_pred, C
    belongs to the step from time k+1 to k+2."""
    T = x_filt.shape[0]
    xs[T - 1] = x_filt[T - 1]
    Ps[T - 1] = P_filt[T - 1]
    for k in range(T - 2, -1, -1):
        Ck = C[k]
        Ckt = np.ascontiguousarray(Ck.T)
        xs[k] = x_filt[k] + Ck @ (xs[k + 1] - x_pred[k])
        P = P_filt[k] + Ck @ (Ps[k + 1] - P_pred[k]) @ Ckt
        Ps[k] = 0.5 * (P + P.T)
