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

from .._core.finiteness import finite_result
from .._core.rts import rts_backward, rts_backward_linear, smoother_gains
from .._core.steady_input import steady_argument
from .._core.validation import check_record
from ..errors import ParameterError, ShapeError
from ..models import LinearGaussianModel, require_model
from ..result import FilterResult
from ..riccati import SteadyState
from ._kernels import ss_loop

__all__ = ["rts_smoother", "steady_state_smoother"]


def _check(model, result) -> None:
    require_model(model)
    if not isinstance(result, FilterResult):
        raise ParameterError(f"result: expected a FilterResult, got {type(result).__name__}")
    check_record("result", result)
    if result.n != model.n:
        raise ShapeError(f"result: state dimension {result.n} does not match the model's n = {model.n}")


@finite_result("the RTS smoother")
def rts_smoother(model: LinearGaussianModel, result: FilterResult, *, F=None, Q=None, B=None,
                 u=None) -> FilterResult:
    """Fixed-interval Rauch-Tung-Striebel smoother on any filter's result.

    Parameters
    ----------
    model : LinearGaussianModel
        The model the filter ran with.
    result : FilterResult
        Filtered means and covariances x(k/k), P(k/k), k = 1..T (a KF, LF or steady-state filter).
    F, Q, B, u : array_like, optional
        The time-varying matrices and control input the filter ran with (default: those recorded in
        ``result.inputs``; values given again must equal them).

    Returns
    -------
    FilterResult
        x(k/T), P(k/T) (method "RTS"), P(k/T) <= P(k/k); with the filter's prior at time 0 in the result,
        x(0/T), P(0/T) as x0, P0.  For irregular time stamps use :func:`rts_smoother_irregular`.

    References
    ----------
    .. [1] H. E. Rauch, F. Tung and C. T. Striebel, "Maximum likelihood estimates of linear dynamic systems",
           AIAA Journal, vol. 3, no. 8, pp. 1445–1450, 1965. doi:10.2514/3.3166
    """
    _check(model, result)
    has0 = result.x0 is not None and result.P0 is not None
    mats = _run_matrices(model, result, F=F, Q=Q, B=B, u=u)
    if mats is None:
        smoothed = rts_backward_linear(result, model.F, model.Q)
        if not has0:
            return smoothed
        return _with_time_zero(result, smoothed, model.F, model.Q, 0.0)
    Fs, Qs = mats["F"], mats["Q"]
    Bu = np.zeros((result.T, model.n)) if mats["Bu"] is None else mats["Bu"]
    xf = np.asarray(result.x, dtype=float)
    Pf = np.asarray(result.P, dtype=float)
    cross = Pf[:-1] @ np.swapaxes(Fs[1:], 1, 2)
    x_pred = np.einsum("tij,tj->ti", Fs[1:], xf[:-1]) + Bu[1:]
    xs, Ps = rts_backward(xf, Pf, x_pred, Fs[1:] @ cross + Qs[1:], cross)
    smoothed = FilterResult(x=xs, P=Ps, method="RTS")
    return _with_time_zero(result, smoothed, Fs[0], Qs[0], Bu[0]) if has0 else smoothed


def _run_matrices(model, result: FilterResult, **given) -> dict | None:
    """The per-step {"F", "Q", "Bu"} the filter ran with: recorded in result.inputs (given ones must
    agree) or from the given F, Q, B, u; None for the model's constant F, Q without control."""
    from ._kalman import step_matrices
    recorded = result.inputs if result.inputs is not None and "F" in result.inputs else None
    if all(v is None for v in given.values()):
        return recorded
    mats = step_matrices(model, result.T, **given)
    if recorded is None:
        return mats
    for key, names, was_given in (("F", "F", given["F"] is not None), ("Q", "Q", given["Q"] is not None),
                                  ("Bu", "B and u", given["B"] is not None)):
        if not was_given:
            continue
        mine, ran = mats[key], recorded[key]
        if ran is None or not np.allclose(mine, ran, rtol=1e-12, atol=1e-12 * np.abs(ran).max()):
            raise ParameterError(f"{names}: not what the filter ran with (recorded in result.inputs); omit "
                                 f"{names} and the smoother uses the run's")
    return recorded


def _with_time_zero(result: FilterResult, smoothed: FilterResult, F0, Q0, Bu0) -> FilterResult:
    """``smoothed`` with x(0/T), P(0/T) from one more RTS step back to the filter's prior x0, P0."""
    x0, P0 = np.asarray(result.x0, dtype=float), np.asarray(result.P0, dtype=float)
    PFt = P0 @ F0.T
    P_pred = F0 @ PFt + Q0
    C = smoother_gains(PFt, 0.5 * (P_pred + P_pred.T))
    x = x0 + C @ (smoothed.x[0] - (F0 @ x0 + Bu0))
    P = P0 + C @ (smoothed.P[0] - P_pred) @ C.T
    return FilterResult(x=smoothed.x, P=smoothed.P, method="RTS", x0=x, P0=0.5 * (P + P.T))


@finite_result("the steady-state smoother")
def steady_state_smoother(model: LinearGaussianModel, result: FilterResult, *,
                          steady: SteadyState | None = None) -> FilterResult:
    """Steady-state RTS smoother: constant gain C = Pe F^T Pp^-1 on a steady-state filter's estimates,
    x(k/T) = x(k/k) + C [x(k+1/T) - F x(k/k)].

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    result : FilterResult
        Typically :func:`steady_state_filter`'s output.
    steady : SteadyState, optional
        A precomputed :func:`mptrack.riccati.steady_state` (the off-line part); solved once per model
        when not given.

    Returns
    -------
    FilterResult
        With the steady-state smoothed covariance Ps, the fixed point of the RTS covariance recursion
        (valid away from both ends).

    References
    ----------
    .. [1] H. E. Rauch, F. Tung and C. T. Striebel, "Maximum likelihood estimates of linear dynamic systems",
           AIAA Journal, vol. 3, no. 8, pp. 1445–1450, 1965. doi:10.2514/3.3166
    """
    _check(model, result)
    ss = steady_argument(model, steady)
    F, Pe, Pp = model.F, ss.P_filt, ss.P_pred
    C = smoother_gains(Pe @ F.T, Pp)
    T = result.T
    x_filt = np.asarray(result.x, dtype=float)
    # x(k/T) = C x(k+1/T) + [x(k/k) - C F x(k/k)]: the steady-state filter's compiled recursion
    # run backwards in time, with A = C, B = I and input u(k) = (I - C F) x(k/k)
    u = np.ascontiguousarray((x_filt @ (np.eye(model.n) - C @ F).T)[-2::-1])
    xs = np.empty_like(x_filt)
    xs[-1] = x_filt[-1]
    ss_loop(C, np.eye(model.n), C, u, x_filt[-1].copy(), xs[-2::-1])
    Psm = scipy.linalg.solve_discrete_lyapunov(C, Pe - C @ Pp @ C.T)
    Psm = 0.5 * (Psm + Psm.T)
    return FilterResult(x=xs, P=np.broadcast_to(Psm, (T, model.n, model.n)), method="SS-RTS")
