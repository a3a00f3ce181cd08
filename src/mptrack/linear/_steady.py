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
    """Steady-state filter x(k+1/k+1) = A x(k/k) + B z(k+1) (SSKF eq. 9-10, SSLF eq. 12-13).

    form        "kalman" (A, B from the REKF/DARE solution) or "lainiotis"
                (A, B from the RELF solution, eq. 13); they are equal (eq. 15).
    steady      a precomputed :func:`mptrack.riccati.steady_state` result (off-line part)
    covariance  "steady": P(k/k) is the steady-state Pe at every step (the papers');
                "exact": the actual error covariance of this constant-gain filter
                started from P0, P <- (I-KH)(F P F^T + Q)(I-KH)^T + K R K^T.
    A NaN measurement row only predicts (x <- F x; with "exact" the covariance too).

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
    """FIR order M: the smallest M >= 1 with ||A^M|| < eps (so ||A^{M-1}|| >= eps),
    Assimakis & Adam 2014, eq. 22.

    ``norm`` is any ``numpy.linalg.norm`` matrix order (2, 'fro', 1, inf, ...).
    The papers' example (eps = 1e-3, spectral norm) gives M = 17.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
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
    """The FIR impulse response C_j = A^j B, j = 0..M-1, as an (M, n, m) array.

    A (n, n), B (n, m), M >= 1 (the result's size is checked against the memory limit first).

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

    M       filter order; by default from ||A^M|| < eps in the given matrix ``norm``
    warmup  for k < M, "truncate" uses the measurements available so far
            (with x0 = 0 this equals the steady-state filter exactly) and
            "steady-state" runs the recursive steady-state filter from x0 there.
    The FIR form needs a complete measurement window: NaN is an error.
    The covariance reported is the steady-state Pe.

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
