"""Steady-state filters (Assimakis & Adam 2014, eqs. 9-16) and the FIR steady-state filter (eqs. 20-22)."""

from __future__ import annotations

from typing import Literal

import numpy as np

from .._core.finiteness import finite_result
from .._core.fir import check_order_rule, coefficients_unchecked
from .._core.steady_input import steady_argument
from .._core.validation import as_matrix, check_allocation, check_int
from ..errors import ConvergenceError, NonFiniteError, ParameterError, ShapeError
from ..models import LinearGaussianModel
from ..result import FilterResult
from ..riccati import SteadyState
from ._common import prepare_inputs
from ._kernels import ss_loop

__all__ = ["steady_state_filter", "fir_filter", "fir_order", "fir_coefficients"]


@finite_result("the steady-state filter")
def steady_state_filter(model: LinearGaussianModel, z, x0=None, P0=None, *,
                        form: Literal["kalman", "lainiotis"] = "kalman",
                        steady: SteadyState | None = None,
                        covariance: Literal["steady", "exact"] = "steady") -> FilterResult:
    """Steady-state filter x(k+1/k+1) = A x(k/k) + B z(k+1) (SSKF eqs. 9-10, SSLF eqs. 12-13 of
    Assimakis & Adam 2014).

    A NaN measurement row only predicts (x <- F x; with ``covariance="exact"`` the covariance too).

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    z : array_like, shape (T, m)
        Measurements z(1..T); NaN components are missing (a NaN row only predicts).
    x0 : array_like, shape (n,), optional
        The prior x(0/0) (default zeros).
    P0 : array_like, shape (n, n), optional
        The prior covariance, used by ``covariance="exact"``.
    form : {"kalman", "lainiotis"}, optional
        A, B from the REKF/DARE solution or from the RELF solution (eq. 13); they are equal (eq. 15).
    steady : SteadyState, optional
        A precomputed :func:`mptrack.riccati.steady_state` (the off-line part); solved once per model
        when not given.
    covariance : {"steady", "exact"}, optional
        ``"steady"``: P(k/k) is the steady-state Pe at every step (the papers'; a read-only broadcast
        view); ``"exact"``: the true error covariance of this constant-gain filter started from P0.

    Returns
    -------
    FilterResult

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    if covariance not in ("steady", "exact"):
        raise ParameterError(f"covariance: expected 'steady' or 'exact', got {covariance!r}")
    z, x, P, missing = prepare_inputs(model, z, x0, P0)
    ss = steady_argument(model, steady, form)
    A, B, F = ss.A, ss.B, model.F
    T = z.shape[0]
    xs = np.empty((T, model.n))
    ss_loop(A, B, F, z, x, xs)
    if covariance == "steady":
        Ps = np.broadcast_to(ss.P_filt, (T, model.n, model.n))
    else:
        # the error covariance of a fixed-gain filter (not a Kalman update): an exception listed in
        # mptrack._core.kalman's docstring
        Ps = np.empty((T, model.n, model.n))
        IKH = np.eye(model.n) - ss.K @ model.H
        KRK = ss.K @ model.R @ ss.K.T
        for k in range(T):
            P = F @ P @ F.T + model.Q
            if not missing[k]:
                P = IKH @ P @ IKH.T + KRK
            Ps[k] = 0.5 * (P + P.T)
    name = "SSKF" if ss.form == "kalman" else "SSLF"
    return FilterResult(x=xs, P=Ps, method=name)


def _matrix_norm(M: np.ndarray, norm) -> float:
    return float(np.linalg.norm(M, norm))


def fir_order(A, eps: float = 1e-3, norm=2, max_order: int = 100_000) -> int:
    """FIR order: the smallest M >= 1 with ||A^M|| < eps (Assimakis & Adam 2014, eq. 22).

    Parameters
    ----------
    A : array_like, shape (n, n)
        The steady-state filter's A, stable.
    eps : float, optional
        The tolerance (the papers' 1e-3 gives M = 17 with the spectral norm).
    norm : optional
        Any ``numpy.linalg.norm`` matrix order (2, "fro", 1, inf, ...).
    max_order : int, optional
        Largest order searched.

    Returns
    -------
    int

    Raises
    ------
    ConvergenceError
        No order up to ``max_order`` meets the rule.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512

    Examples
    --------
    >>> from mptrack.linear import fir_order
    >>> from mptrack.models import assimakis_model_b
    >>> from mptrack.riccati import steady_state
    >>> fir_order(steady_state(assimakis_model_b()).A)
    17
    """
    A = as_matrix("A", A)
    if A.shape[0] != A.shape[1]:
        raise ShapeError(f"A: expected a square matrix, got shape {A.shape}")
    eps = check_order_rule(eps, norm)
    max_order = check_int("max_order", max_order, minimum=1)
    rho = max(abs(np.linalg.eigvals(A)))
    if rho >= 1.0:
        raise ConvergenceError(
            f"A: spectral radius {rho:.6g} >= 1, ||A^M|| never falls below eps; the FIR form does not exist")
    # ||A^M|| >= rho^M in every norm, so no M with rho^M >= eps qualifies: the scan starts at the last of
    # them (less a margin for the rounding of rho), A^start by repeated squaring; a slowly decaying A
    # (rho = 0.999999, eps = 1e-12: M ~ 2.8e7) costs a few dozen products instead of M
    start = 1 if rho == 0.0 or eps >= 1.0 else max(1, int(np.floor(np.log(eps) / np.log(rho))) - 1)
    if start > max_order:
        raise ConvergenceError(f"max_order: ||A^M|| >= rho^M >= {eps:g} for every M up to {start} "
                               f"(spectral radius rho = {rho:.6g}), more than max_order = {max_order}")
    power = np.linalg.matrix_power(A, start)
    for M in range(start, max_order + 1):  # M >= 1: eq. 22 with M = 0 would be an empty sum
        if _matrix_norm(power, norm) < eps:
            return M
        power = power @ A
    raise ConvergenceError(f"max_order: ||A^M|| is still >= {eps:g} at M = {max_order}")


@finite_result("the FIR coefficients")
def fir_coefficients(A, B, M: int) -> np.ndarray:
    """The FIR impulse response C_j = A^j B, j = 0..M-1.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
    M : int
        The order, >= 1.

    Returns
    -------
    ndarray, shape (M, n, m)

    Raises
    ------
    ResourceError
        The result would exceed the memory limit.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    A = as_matrix("A", A)
    if A.shape[0] != A.shape[1]:
        raise ShapeError(f"A: expected a square matrix, got shape {A.shape}")
    B = as_matrix("B", B, A.shape[0], None)
    M = check_int("M", M, minimum=1)
    check_allocation("M", M, 8.0 * M * B.size)
    return coefficients_unchecked(A, B, M)


@finite_result("the FIR filter")
def fir_filter(model: LinearGaussianModel, z, x0=None, P0=None, *, eps: float = 1e-3, norm=2,
               M: int | None = None, steady: SteadyState | None = None,
               warmup: Literal["truncate", "steady-state"] = "truncate") -> FilterResult:
    """FIR steady-state filter x(k/k) = sum_{j<M} A^j B z(k-j) (Assimakis & Adam 2014, eq. 22).

    The FIR form needs a complete measurement window (NaN is an error); the covariance reported is the
    steady-state Pe.

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    z : array_like, shape (T, m)
        Measurements z(1..T), complete.
    x0 : array_like, shape (n,), optional
        The prior x(0/0) (default zeros).
    P0 : array_like, shape (n, n), optional
        The prior covariance (kept in the result).
    eps : float, optional
        The order rule's tolerance: M is the smallest with ||A^M|| < eps.
    norm : optional
        The matrix norm of the order rule (any ``numpy.linalg.norm`` order).
    M : int, optional
        The filter order (default from ``eps`` and ``norm``).
    steady : SteadyState, optional
        A precomputed :func:`mptrack.riccati.steady_state` (the off-line part); solved once per model
        when not given.
    warmup : {"truncate", "steady-state"}, optional
        For k < M: the measurements available so far (with x0 = 0 exactly the steady-state filter), or the
        recursive steady-state filter from x0.

    Returns
    -------
    FilterResult

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    z, x0, P0, missing = prepare_inputs(model, z, x0, P0)
    if missing.any():
        k = int(np.argmax(missing))
        raise NonFiniteError(f"z: the FIR filter needs every measurement; row {k} has NaN "
                             "(use steady_state_filter, which predicts through gaps)")
    if warmup not in ("truncate", "steady-state"):
        raise ParameterError(f"warmup: expected 'truncate' or 'steady-state', got {warmup!r}")
    ss = steady_argument(model, steady)
    check_order_rule(eps, norm)
    M = fir_order(ss.A, eps, norm) if M is None else check_int("M", M, minimum=1)
    T = z.shape[0]
    C = coefficients_unchecked(ss.A, ss.B, min(M, T))   # the window never reaches further back than T
    xs = np.zeros((T, model.n))
    for j in range(min(M, T)):
        xs[j:] += z[: T - j] @ C[j].T
    if warmup == "steady-state":
        head = min(M - 1, T)
        if head:
            xs[:head] = steady_state_filter(model, z[:head], x0, steady=ss).x
    Ps = np.broadcast_to(ss.P_filt, (T, model.n, model.n))
    return FilterResult(x=xs, P=Ps, method="FIR")
