"""N-step prediction: the steady-state predictor of Assimakis et al. 2016 (eqs. 13-20) and the
inverse-free prediction from any filter's estimates.

Assimakis et al. 2016 predict N >= 1 steps ahead with a recursion of the same cost as the
steady-state filter (eq. 19):

    x(k+N/k) = A_N x(k+N-1/k-1) + B_N z(k),
    A_N = F^N (I - K H) F^{-(N-1)},   B_N = F^N K                       (eq. 20)

started from x(N/0) = F^N x(0/0).  It equals x(k+N/k) = F^N x(k/k) with the
steady-state filter's x(k/k) (eqs. 13-14): substituting x(k/k) = (I - KH)
x(k/k-1) + K z(k) and x(k/k-1) = F^{-(N-1)} x(k+N-1/k-1) gives eq. 19, which
is why A_N needs F^{-1} for N >= 2 and the inverse-free form does not.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from .._core.finiteness import finite_result
from .._core.lyapunov import power_sum_unchecked
from .._core.steady_input import steady_argument
from .._core.validation import as_array, check_int, check_record
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..models import LinearGaussianModel, require_model
from ..result import FilterResult
from ..riccati import SteadyState
from ._common import prepare_inputs
from ._kernels import ss_loop
from ._steady import steady_state_filter

__all__ = [
    "prediction_matrices",
    "prediction_covariance",
    "steady_state_predictor",
    "predict_ahead",
]


def prediction_matrices(model: LinearGaussianModel, N: int, *,
                        steady: SteadyState | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(A_N, B_N) of the steady-state N-step predictor (Assimakis et al. 2016, eq. 20).

    A_N = F^N (I - K H) F^-(N-1) and B_N = F^N K with K the steady-state gain; N = 1 gives
    A_1 = F (I - K H), B_1 = F K (eq. 16).

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    N : int
        Steps ahead, >= 1.
    steady : SteadyState, optional
        A precomputed :func:`mptrack.riccati.steady_state` (the off-line part); solved once per model
        when not given.

    Returns
    -------
    A_N : ndarray, shape (n, n)
    B_N : ndarray, shape (n, m)

    Raises
    ------
    SingularMatrixError
        F is singular and N >= 2 (x(k/k-1) can only be recovered through F^-(N-1)); use
        :func:`steady_state_predictor` with ``method="inverse-free"``.

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    """
    require_model(model)
    N = check_int("N", N, minimum=1)
    ss = steady_argument(model, steady)
    F, K, H = model.F, ss.K, model.H
    FN = np.linalg.matrix_power(F, N)
    A = FN @ (np.eye(model.n) - K @ H)
    if N >= 2:
        FN1 = np.linalg.matrix_power(F, N - 1)
        cond = np.linalg.cond(FN1)
        if not np.isfinite(cond) or cond > 1e12:
            rank = np.linalg.matrix_rank(F)
            raise SingularMatrixError(
                f"model.F: singular (rank {rank} < n = {model.n}, cond(F^{N - 1}) = {cond:.3g}); "
                f"A_N = F^N (I - KH) F^-(N-1) of Assimakis et al. 2016 eq. 20 needs F^-1 for N = {N} >= 2 "
                "because the recursion keeps x(k+N-1/k-1) instead of x(k/k); "
                "use method='inverse-free' (x(k+N/k) = F^N x(k/k)) or predict_ahead")
        A = np.linalg.solve(FN1.T, A.T).T  # A F^-(N-1)
    return A, FN @ K


@finite_result("the N-step prediction covariance")
def prediction_covariance(model: LinearGaussianModel, P_filt, N: int) -> np.ndarray:
    """The N-step prediction covariance P(k+N/k) = F^N P(k/k) F^NT + sum_{j<N} F^j Q F^jT.

    F^N and the sum come from repeated squaring, so the cost grows with log N.

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    P_filt : array_like, shape (n, n) or (T, n, n)
        One filtered covariance or a sequence.
    N : int
        Steps ahead, >= 1.

    Returns
    -------
    ndarray
        Of ``P_filt``'s shape.
    """
    require_model(model)
    N = check_int("N", N, minimum=1)
    P = as_array("P_filt", P_filt)
    if P.ndim not in (2, 3) or P.shape[-2:] != (model.n, model.n):
        raise ShapeError(f"P_filt: expected shape ({model.n}, {model.n}) or (T, {model.n}, {model.n}), "
                         f"got shape {P.shape}")
    FN, S = power_sum_unchecked(model.F, model.Q, N)
    P = FN @ P @ FN.T + S
    return 0.5 * (P + np.swapaxes(P, -1, -2))


@finite_result("the steady-state predictor")
def steady_state_predictor(model: LinearGaussianModel, z, N: int = 1, x0=None, *,
                           steady: SteadyState | None = None,
                           method: Literal["recursive", "inverse-free"] = "recursive") -> FilterResult:
    """Steady-state N-step prediction x(k+N/k), k = 1..T (Assimakis et al. 2016, eqs. 15-20).

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    z : array_like, shape (T, m)
        Measurements z(1..T); NaN components are missing (a NaN row only predicts).
    N : int, optional
        Steps ahead, >= 1.
    x0 : array_like, shape (n,), optional
        The prior x(0/0) (default 0, as in the paper).
    steady : SteadyState, optional
        A precomputed :func:`mptrack.riccati.steady_state` (the off-line part); solved once per model
        when not given.
    method : {"recursive", "inverse-free"}, optional
        The paper's x(k+N/k) = A_N x(k+N-1/k-1) + B_N z(k) from x(N/0) = F^N x0 (needs F invertible for
        N >= 2), or x(k+N/k) = F^N x(k/k) from the steady-state filter; both give the same numbers.

    Returns
    -------
    FilterResult
        Row k-1 holds x(k+N/k), with the N-step covariance F^N Pe F^NT + sum_{j<N} F^j Q F^jT.

    Raises
    ------
    SingularMatrixError
        ``method="recursive"`` with N >= 2 and an ill-conditioned F.

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    """
    require_model(model)
    N = check_int("N", N, minimum=1)
    if method not in ("recursive", "inverse-free"):
        raise ParameterError(f"method: expected 'recursive' or 'inverse-free', got {method!r}")
    z, x0, _, _ = prepare_inputs(model, z, x0, None)
    ss = steady_argument(model, steady)
    T, n = z.shape[0], model.n
    FN = np.linalg.matrix_power(model.F, N)
    if method == "inverse-free":
        xs = steady_state_filter(model, z, x0, steady=ss).x @ FN.T
    else:
        A, B = prediction_matrices(model, N, steady=ss)
        xs = np.empty((T, n))
        # eq. 19 is the steady-state filter's recursion with (A_N, B_N), from x(N/0) = F^N x0;
        # a missing z(k) gives x(k/k) = x(k/k-1), so x(k+N/k) = F x(k+N-1/k-1)
        ss_loop(A, B, model.F, z, FN @ x0, xs)
    P = np.broadcast_to(prediction_covariance(model, ss.P_filt, N), (T, n, n))
    return FilterResult(x=xs, P=P, method=f"SS-predictor(N={N})")


@finite_result("the N-step prediction")
def predict_ahead(model: LinearGaussianModel, result: FilterResult, N: int) -> FilterResult:
    """N-step predictions from any filter's estimates (Assimakis et al. 2016, eq. 14).

    x(k+N/k) = F^N x(k/k) and P(k+N/k) = F^N P(k/k) F^NT + sum_{j<N} F^j Q F^jT.  With a
    :func:`kalman_filter` result this is the time-varying Kalman N-step predictor; with
    :func:`steady_state_filter` the inverse-free steady-state predictor.

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    result : FilterResult
        A filter's result.
    N : int
        Steps ahead, >= 1.

    Returns
    -------
    FilterResult
        Row k-1 holds x(k+N/k): compare with the truth shifted by N.

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    """
    require_model(model)
    N = check_int("N", N, minimum=1)
    if not isinstance(result, FilterResult):
        raise ParameterError(f"result: expected a FilterResult, got {type(result).__name__}")
    check_record("result", result)
    if result.n != model.n:
        raise ShapeError(f"result: state dimension {result.n} does not match the model's n = {model.n}")
    FN = np.linalg.matrix_power(model.F, N)
    return FilterResult(x=result.x @ FN.T, P=prediction_covariance(model, result.P, N),
                        method=f"{result.method}-predict(N={N})")

