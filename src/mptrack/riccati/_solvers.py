"""Steady-state solutions of the filter Riccati equations.

REKF (seed 000 eq. 11), for the steady-state prediction covariance Pp:

    Pp = Q + F Pp F^T - F Pp H^T [H Pp H^T + R]^{-1} H Pp F^T

solved three independent ways: the per-step recursion, a doubling algorithm
(the structure-preserving doubling algorithm, SDA) and the algebraic solution
(scipy's DARE).  RELF (seed 000 eq. 14) for the Lainiotis form:

    Pe = Pn + Fn [I + Pe On]^{-1} Pe Fn^T.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg

from .._validation import check_covariance, check_int, check_positive
from ..errors import ConvergenceError, NotDetectableError, ParameterError
from ..models import LinearGaussianModel, require_model
from ._checks import check_detectable, check_stabilisable
from ._lainiotis import lainiotis_parameters

__all__ = [
    "SteadyState",
    "steady_state",
    "riccati_step",
    "riccati_residual",
    "METHODS",
]

Method = Literal["dare", "doubling", "per-step"]
METHODS: tuple[str, ...] = ("dare", "doubling", "per-step")


@dataclass(frozen=True, eq=False)
class SteadyState:
    """The steady-state filter of a model.

    K        steady-state gain (n, m)
    P_pred   steady-state prediction error covariance Pp (n, n)
    P_filt   steady-state estimation error covariance Pe (n, n)
    A, B     the steady-state filter x(k+1/k+1) = A x(k/k) + B z(k+1):
             A = (I - K H) F and B = K (Kalman form, eq. 10) or
             A = Fn [I + Pe On]^{-1}, B = Kn + Fn [I + Pe On]^{-1} Pe Km (Lainiotis form, eq. 13)
    form     "kalman" or "lainiotis"
    method   which solver produced it
    iterations          per-step iterations or doubling steps taken
    steady_state_time   time step k from which the per-step recursion (from P0)
                        stays within the tolerance (per-step method; None otherwise)
    residual            relative residual of the REKF at P_pred
    """

    K: np.ndarray
    P_pred: np.ndarray
    P_filt: np.ndarray
    A: np.ndarray
    B: np.ndarray
    form: str
    method: str
    iterations: int
    steady_state_time: int | None
    residual: float


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)


def _gain(model: LinearGaussianModel, P_pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalman gain K and innovation covariance S for a prediction covariance."""
    H = model.H
    S = _sym(H @ P_pred @ H.T + model.R)
    K = scipy.linalg.solve(S, H @ P_pred, assume_a="pos").T
    return K, S


def riccati_step(model: LinearGaussianModel, P_pred: np.ndarray) -> np.ndarray:
    """One step of the REKF recursion: P(k+1/k) from P(k/k-1)."""
    K, S = _gain(model, P_pred)
    P_filt = _sym(P_pred - K @ S @ K.T)
    return _sym(model.Q + model.F @ P_filt @ model.F.T)


def riccati_residual(model: LinearGaussianModel, P_pred: np.ndarray) -> float:
    """||REKF(Pp) - Pp||_F / max(1, ||Pp||_F)."""
    diff = riccati_step(model, P_pred) - P_pred
    return float(np.linalg.norm(diff) / max(1.0, np.linalg.norm(P_pred)))


def _check_exists(model: LinearGaussianModel) -> None:
    check_detectable(model.F, model.H)
    check_stabilisable(model.F, model.noise_factor())


def _per_step(model, P0, tol, max_iter):
    F = model.F
    P_filt = P0
    P_pred = _sym(model.Q + F @ P_filt @ F.T)
    for k in range(1, max_iter + 1):
        P_next = riccati_step(model, P_pred)
        if np.linalg.norm(P_next - P_pred) <= tol * max(np.linalg.norm(P_next), np.finfo(float).tiny):
            return P_next, k
        P_pred = P_next
    raise ConvergenceError(
        f"max_iter: the per-step Riccati recursion did not converge to tol={tol:g} "
        f"in {max_iter} iterations")


def _doubling(model, tol, max_iter):
    """Structure-preserving doubling (Chu, Fan & Lin 2005) for the filter DARE.

    With A0 = F^T, G0 = H^T R^{-1} H, H0 = Q:
        W = I + G_k H_k
        A_{k+1} = A_k W^{-1} A_k
        G_{k+1} = G_k + A_k W^{-1} G_k A_k^T
        H_{k+1} = H_k + A_k^T H_k W^{-1} A_k
    H_k is the prediction covariance after 2^k per-step iterations from P = 0.
    """
    n = model.n
    Ak = model.F.T.copy()
    Gk = _sym(model.H.T @ np.linalg.solve(model.R, model.H))
    Hk = model.Q.copy()
    eye = np.eye(n)
    for k in range(1, max_iter + 1):
        W = eye + Gk @ Hk
        WA = np.linalg.solve(W, Ak)
        WG = np.linalg.solve(W, Gk)
        H_next = _sym(Hk + Ak.T @ Hk @ WA)
        Gk = _sym(Gk + Ak @ WG @ Ak.T)
        Ak = Ak @ WA
        done = np.linalg.norm(H_next - Hk) <= tol * max(np.linalg.norm(H_next), np.finfo(float).tiny)
        Hk = H_next
        if done:
            return Hk, k
    raise ConvergenceError(
        f"max_iter: the doubling algorithm did not converge to tol={tol:g} in {max_iter} doublings")


def _dare(model):
    try:
        P = scipy.linalg.solve_discrete_are(model.F.T, model.H.T, model.Q, model.R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise NotDetectableError(f"model: scipy's DARE found no stabilising solution ({exc})") from None
    return _sym(P), 0


def _relf(model, P0, tol, max_iter):
    """Per-step RELF recursion Pe <- Pn + Fn [I + Pe On]^{-1} Pe Fn^T (seed 000 eq. 14)."""
    lp = lainiotis_parameters(model)
    eye = np.eye(model.n)
    Pe = P0
    for k in range(1, max_iter + 1):
        P_next = _sym(lp.Pn + lp.Fn @ np.linalg.solve(eye + Pe @ lp.On, Pe) @ lp.Fn.T)
        if np.linalg.norm(P_next - Pe) <= tol * max(np.linalg.norm(P_next), np.finfo(float).tiny):
            return P_next, k
        Pe = P_next
    raise ConvergenceError(
        f"max_iter: the per-step Lainiotis Riccati recursion did not converge to tol={tol:g} "
        f"in {max_iter} iterations")


def steady_state(model: LinearGaussianModel, method: Method = "dare", *,
                 form: Literal["kalman", "lainiotis"] = "kalman", P0=None,
                 tol: float = 1e-13, max_iter: int = 100_000) -> SteadyState:
    """Steady-state gain, covariances and filter matrices of ``model``.

    method  "dare" (scipy's algebraic solver), "doubling" (SDA) or "per-step"
            (iterate the Riccati recursion from P(0/0) = P0, default 0).
    form    "kalman": A = (I - KH) F, B = K from the REKF solution (eq. 10-11);
            "lainiotis": Pe from the RELF recursion (eq. 14) and
            A, B from eq. 13 (only with method "per-step", the paper's choice).

    Raises NotDetectableError / NotStabilisableError when no stabilising
    steady state exists, ConvergenceError when an iteration does not converge.
    """
    require_model(model)
    if method not in METHODS:
        raise ParameterError(f"method: expected one of {METHODS}, got {method!r}")
    if form not in ("kalman", "lainiotis"):
        raise ParameterError(f"form: expected 'kalman' or 'lainiotis', got {form!r}")
    tol = check_positive("tol", tol)
    max_iter = check_int("max_iter", max_iter, minimum=1)
    P0 = np.zeros((model.n, model.n)) if P0 is None else check_covariance("P0", P0, model.n)
    _check_exists(model)
    n = model.n
    eye = np.eye(n)

    if form == "lainiotis":
        if method != "per-step":
            raise ParameterError("method: the Lainiotis form is solved with method='per-step' (RELF)")
        Pe, iters = _relf(model, P0, tol, max_iter)
        lp = lainiotis_parameters(model)
        inv_term = np.linalg.solve((eye + Pe @ lp.On).T, lp.Fn.T).T  # Fn [I + Pe On]^{-1}
        A = inv_term
        B = lp.Kn + inv_term @ Pe @ lp.Km
        P_pred = _sym(model.Q + model.F @ Pe @ model.F.T)
        K, _ = _gain(model, P_pred)
        return SteadyState(K=K, P_pred=P_pred, P_filt=Pe, A=A, B=B, form=form, method=method,
                           iterations=iters, steady_state_time=iters,
                           residual=riccati_residual(model, P_pred))

    if method == "dare":
        P_pred, iters = _dare(model)
        ss_time = None
    elif method == "doubling":
        P_pred, iters = _doubling(model, tol, max_iter)
        ss_time = None
    else:
        P_pred, iters = _per_step(model, P0, tol, max_iter)
        ss_time = iters
    K, S = _gain(model, P_pred)
    P_filt = _sym(P_pred - K @ S @ K.T)
    A = (eye - K @ model.H) @ model.F
    return SteadyState(K=K, P_pred=P_pred, P_filt=P_filt, A=A, B=K.copy(), form=form,
                       method=method, iterations=iters, steady_state_time=ss_time,
                       residual=riccati_residual(model, P_pred))
