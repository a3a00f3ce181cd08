"""Fixed-interval Rauch-Tung-Striebel smoothing of a filter's estimates, and its steady state.

RTS (Rauch, Tung & Striebel 1965; Anderson & Moore 1979, sec. 7.4), for
k = T-1 down to 1, from x(T/T), P(T/T):

    C(k)   = P(k/k) F^T P(k+1/k)^{-1}
    x(k/T) = x(k/k) + C(k) [x(k+1/T) - x(k+1/k)]
    P(k/T) = P(k/k) + C(k) [P(k+1/T) - P(k+1/k)] C(k)^T

with x(k+1/k) = F x(k/k) and P(k+1/k) = F P(k/k) F^T + Q.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ..errors import ParameterError, ShapeError
from ..models import LinearGaussianModel
from ..riccati import SteadyState
from ._result import FilterResult
from ._steady import _steady

__all__ = ["rts_smoother", "steady_state_smoother"]


def _check(model, result) -> None:
    if not isinstance(model, LinearGaussianModel):
        raise ParameterError(f"model: expected a LinearGaussianModel, got {type(model).__name__}")
    if not isinstance(result, FilterResult):
        raise ParameterError(f"result: expected a FilterResult, got {type(result).__name__}")
    if result.n != model.n:
        raise ShapeError(f"result: state dimension {result.n} does not match the model's n = {model.n}")


def _smoother_gain(P_filt: np.ndarray, F: np.ndarray, P_pred: np.ndarray) -> np.ndarray:
    """C = P_filt F^T P_pred^{-1}; a pseudo-inverse where P_pred is singular (zero prior, rank-deficient Q)."""
    PFt = P_filt @ F.T
    try:
        return scipy.linalg.solve(P_pred, PFt.T, assume_a="pos").T
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return PFt @ np.linalg.pinv(P_pred)


def rts_smoother(model: LinearGaussianModel, result: FilterResult) -> FilterResult:
    """Fixed-interval RTS smoother on a filter result (x(k/k), P(k/k), k = 1..T).

    model   the LinearGaussianModel the filter ran with (F, Q)
    result  a FilterResult with filtered means and covariances, e.g. from
            :func:`kalman_filter` (any filter returning the exact P(k/k) works;
            the steady-state filters' constant Pe gives the steady-state smoother)

    Returns a FilterResult with the smoothed x(k/T), P(k/T) (method "RTS").
    P(k/T) <= P(k/k) in the positive semi-definite order.
    """
    _check(model, result)
    F, Q = model.F, model.Q
    T, n = result.T, result.n
    xs = np.array(result.x, dtype=float)
    Ps = np.array(result.P, dtype=float)
    for k in range(T - 2, -1, -1):
        P_filt = Ps[k]
        x_pred = F @ result.x[k]
        P_pred = F @ P_filt @ F.T + Q
        P_pred = 0.5 * (P_pred + P_pred.T)
        C = _smoother_gain(P_filt, F, P_pred)
        xs[k] = result.x[k] + C @ (xs[k + 1] - x_pred)
        P = P_filt + C @ (Ps[k + 1] - P_pred) @ C.T
        Ps[k] = 0.5 * (P + P.T)
    return FilterResult(x=xs, P=Ps, method="RTS")


def steady_state_smoother(model: LinearGaussianModel, result: FilterResult, *,
                          steady: SteadyState | None = None) -> FilterResult:
    """Steady-state RTS smoother: constant gain C = Pe F^T Pp^{-1} on the
    steady-state filter's estimates, x(k/T) = x(k/k) + C [x(k+1/T) - F x(k/k)].

    The covariance reported is the steady-state smoothed covariance Ps, the
    solution of the Lyapunov equation Ps = C Ps C^T + Pe - C Pp C^T (the
    fixed point of the RTS covariance recursion, valid away from both ends).
    ``result`` is typically :func:`steady_state_filter`'s output.
    """
    _check(model, result)
    ss = _steady(model, steady, "kalman")
    F, Pe, Pp = model.F, ss.P_filt, ss.P_pred
    C = _smoother_gain(Pe, F, Pp)
    T = result.T
    xs = np.array(result.x, dtype=float)
    x_pred = result.x @ F.T  # row k: x(k+1/k) = F x(k/k)
    for k in range(T - 2, -1, -1):
        xs[k] = result.x[k] + C @ (xs[k + 1] - x_pred[k])
    Psm = scipy.linalg.solve_discrete_lyapunov(C, Pe - C @ Pp @ C.T)
    Psm = 0.5 * (Psm + Psm.T)
    return FilterResult(x=xs, P=np.broadcast_to(Psm, (T, model.n, model.n)), method="SS-RTS")
