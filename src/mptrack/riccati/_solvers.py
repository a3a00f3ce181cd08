"""Steady-state solutions of the filter Riccati equations.

REKF (Assimakis & Adam 2014, eq. 11), for the steady-state prediction covariance Pp:

    Pp = Q + F Pp F^T - F Pp H^T [H Pp H^T + R]^{-1} H Pp F^T

solved three independent ways: the per-step recursion, a doubling algorithm
(the structure-preserving doubling algorithm, SDA) and the algebraic solution
(scipy's DARE).  RELF (Assimakis & Adam 2014, eq. 14) for the Lainiotis form:

    Pe = Pn + Fn [I + Pe On]^{-1} Pe Fn^T.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg

from .._core.blas import one_blas_thread
from .._core.finiteness import _overflow, renamed, require_finite
from .._core.validation import check_covariance, check_int, check_positive
from ..errors import ConvergenceError, MptrackError, ParameterError
from ..models import LinearGaussianModel, require_model
from ._checks import check_detectable, check_stabilisable, undriven_modes
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

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
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
    """One step of the Kalman filter's Riccati recursion (REKF): P(k+1/k) from P(k/k-1).

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    P_pred : array_like, shape (n, n)
        P(k/k-1), symmetric positive semi-definite.

    Returns
    -------
    ndarray, shape (n, n)
        P(k+1/k).

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    require_model(model)
    P_pred = check_covariance("P_pred", P_pred, model.n)
    with np.errstate(all="ignore"):
        try:
            P_next = _riccati_step(model, P_pred)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise _overflow("the Riccati step", dict(model=model, P_pred=P_pred), exc) from None
    require_finite("the Riccati step", P_next, model=model, P_pred=P_pred)
    return P_next


def _riccati_step(model: LinearGaussianModel, P_pred: np.ndarray) -> np.ndarray:
    K, S = _gain(model, P_pred)
    P_filt = _sym(P_pred - K @ S @ K.T)
    return _sym(model.Q + model.F @ P_filt @ model.F.T)


def riccati_residual(model: LinearGaussianModel, P_pred: np.ndarray) -> float:
    """Relative residual of a Riccati solution: ||REKF(P) - P||_F / max(1, ||P||_F).

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    P_pred : array_like, shape (n, n)
        A candidate steady-state P(k+1/k).

    Returns
    -------
    float
    """
    P_next = riccati_step(model, P_pred)
    value = _residual(model, P_pred, P_next)
    require_finite("the Riccati residual", value, model=model, P_pred=P_pred)
    return value


def _residual(model, P_pred, P_next=None) -> float:
    """||P_next - P_pred||_F / max(1, ||P_pred||_F), formed in units of the larger entry of the two, so
    that matrices with entries beyond 1e154 (whose squares overflow) have a residual too; inf only when
    the residual itself is beyond the float64 range."""
    if P_next is None:
        P_next = _riccati_step(model, P_pred)
    unit = max(float(np.abs(P_next).max()), float(np.abs(P_pred).max()), np.finfo(float).tiny)
    size, scale = _fro(P_next / unit - P_pred / unit), _fro(P_pred / unit)
    with np.errstate(over="ignore"):
        return float(size / scale if unit * scale >= 1.0 else unit * size)


def _fro(M: np.ndarray) -> float:
    """||M||_F in units of its largest entry: numpy squares the entries, which overflow beyond 1e154 and
    vanish below 1e-154."""
    big = float(np.abs(M).max(initial=0.0))
    if not big > 0.0 or not np.isfinite(big):
        return big
    return big * float(np.linalg.norm(M / big))


def _check_exists(model: LinearGaussianModel) -> None:
    with renamed(F="model", H="model", Q_factor="model"):       # the caller passed the model
        check_detectable(model.F, model.H)
        check_stabilisable(model.F, model.noise_factor())


#: The relative step at which the per-step recursion is "in steady state" (the steady-state time
#: k of the papers' experiments); the iteration itself goes on to the rounding level.
STEADY_TOL = 1e-13
_EPS = np.finfo(float).eps


#: Every this many iterations, the relative steps of the last 100 must all be below _NO_PROGRESS,
#: or the recursion is taken to be lost in rounding (a converging one is far below it by then).
_PROGRESS_EVERY = 1000
_NO_PROGRESS = 0.1
#: A per-step recursion whose rate of convergence (measured over the last _PROGRESS_EVERY steps)
#: needs more iterations than this in all stops with advice instead (~5 s; the doubling algorithm
#: reaches the same fixed point in about log2 of that many steps).
MAX_PER_STEP = 1_000_000


def _iterate(step, P, tol, max_iter, what):
    """Iterate P <- step(P) from P.

    Stopping rule: with ``tol`` given, the first relative step ||dP|| <= tol ||P||.  By default
    (tol None) the iteration goes on until the step is at the rounding level (<= 4 eps ||P||) or
    stops shrinking for 3 iterations in a row (rounding noise), which meets scipy's residual bar
    on its DARE test cases; the first k with a relative step <= STEADY_TOL is reported as the
    steady-state time.  Returns (P, iterations, steady-state time)."""
    ss_time = None
    last, stalled, worst, checked = np.inf, 0, 0.0, None
    for k in range(1, max_iter + 1):
        P_next = step(P)
        size, scale = _step_norms(P_next, P)
        if not np.isfinite(size):
            return np.full_like(P_next, np.inf), k, ss_time   # reported as an overflow by the caller
        if k % _PROGRESS_EVERY > _PROGRESS_EVERY - 100:   # the last 100 steps before each check
            worst = max(worst, size / scale)
        if k % _PROGRESS_EVERY == 0:   # a recursion lost in rounding never settles: stop early
            if worst > _NO_PROGRESS:
                raise ConvergenceError(
                    f"method: {what} is not converging (relative steps up to {worst:.3g} after {k} "
                    "iterations: the model is too ill-conditioned for it in float64); use method='dare'")
            worst = 0.0
            _check_rate(checked, size / scale, k, tol, max_iter, what)
            checked = size / scale
        if ss_time is None and size <= STEADY_TOL * scale:
            ss_time = k
        if tol is not None:
            if size <= tol * scale:
                return P_next, k, k
        else:
            stalled = stalled + 1 if size >= last else 0
            if size <= 4 * _EPS * scale or (stalled >= 3 and ss_time is not None):
                return P_next, k, ss_time
        last = size
        P = P_next
    raise ConvergenceError(
        f"max_iter: {what} did not converge to tol={tol if tol is not None else 'rounding level'} "
        f"in {max_iter} iterations")


def _step_norms(new: np.ndarray, old: np.ndarray) -> tuple[float, float]:
    """(||new - old||_F, ||new||_F), formed in units of the largest entry: entries beyond 1e154, whose
    squares overflow, still have norms (the step used to read as infinite there, and the iterations
    stopped after one step with an unconverged P).  inf only for norms beyond the float64 range."""
    with np.errstate(over="ignore", invalid="ignore"):       # halves: the difference cannot overflow
        return 2.0 * _fro(new / 2.0 - old / 2.0), max(_fro(new), np.finfo(float).tiny)


def _check_rate(before: float | None, now: float, k: int, tol, max_iter: int, what: str) -> None:
    """Stop a recursion that converges too slowly to finish: from the relative step ``before`` (at
    k - _PROGRESS_EVERY) and ``now`` (at k), the linear rate r per step, and the iterations it still
    needs to reach the stopping rule's step (tol, or the rounding level)."""
    if not before or not 0.0 < now < before:
        return
    rate = (now / before) ** (1.0 / _PROGRESS_EVERY)
    target = tol if tol is not None else 4 * _EPS
    if rate >= 1.0 or now <= target:
        return
    needed = k + np.log(target / now) / np.log(rate)
    if needed > max_iter:
        raise ConvergenceError(
            f"max_iter: {what} converges by a factor {rate:.9f} per step: it needs about {needed:.3g} "
            f"iterations to reach tol={tol if tol is not None else 'rounding level'}, more than max_iter = "
            f"{max_iter}; use method='doubling' or 'dare' (the same fixed point, in far fewer steps)")
    if needed > MAX_PER_STEP:
        raise ConvergenceError(
            f"method: {what} converges by a factor {rate:.9f} per step: it needs about {needed:.3g} "
            f"iterations (more than {MAX_PER_STEP:,}); use method='doubling' or 'dare' (the same fixed "
            "point, in far fewer steps)")


def _per_step(model, P0, tol, max_iter):
    F = model.F
    P_pred = _sym(model.Q + F @ P0 @ F.T)
    return _iterate(lambda P: _riccati_step(model, P), P_pred, tol, max_iter,
                    "the per-step Riccati recursion")


def _doubling(model, tol, max_iter, X0=None):
    """Structure-preserving doubling (Chu, Fan, Lin & Wang 2004) for the filter DARE.

    With A0 = F^T, G0 = H^T R^{-1} H, H0 = Q:
        W = I + G_k H_k
        A_{k+1} = A_k W^{-1} A_k
        G_{k+1} = G_k + A_k W^{-1} G_k A_k^T
        H_{k+1} = H_k + A_k^T H_k W^{-1} A_k
    H_k is the prediction covariance after 2^k per-step iterations from P = 0; from a start
    X0 instead, that covariance is H_k + A_k^T X0 (I + G_k X0)^{-1} A_k (used when F has undriven
    modes outside the unit circle, which the iteration from 0 never excites).
    Stopping rule as :func:`_iterate`.
    """
    n = model.n
    Ak = model.F.T.copy()
    Gk = _sym(model.H.T @ np.linalg.solve(model.R, model.H))
    Hk = model.Q.copy()
    eye = np.eye(n)
    Yk = Hk if X0 is None else _sym(Hk + Ak.T @ X0 @ np.linalg.solve(eye + Gk @ X0, Ak))
    last, stalled = np.inf, 0
    for k in range(1, max_iter + 1):
        W = eye + Gk @ Hk
        WA = np.linalg.solve(W, Ak)
        WG = np.linalg.solve(W, Gk)
        Hk = _sym(Hk + Ak.T @ Hk @ WA)
        Gk = _sym(Gk + Ak @ WG @ Ak.T)
        Ak = Ak @ WA
        Y_next = Hk if X0 is None else _sym(Hk + Ak.T @ X0 @ np.linalg.solve(eye + Gk @ X0, Ak))
        size, scale = _step_norms(Y_next, Yk)
        Yk = Y_next
        if not np.isfinite(size):
            return np.full_like(Yk, np.inf), k      # reported as an overflow by the caller
        if tol is not None:
            if size <= tol * scale:
                return Yk, k
        else:
            stalled = stalled + 1 if size >= last and size <= 1e3 * STEADY_TOL * scale else 0
            if size <= 4 * _EPS * scale or stalled >= 2:
                return Yk, k
        last = size
    raise ConvergenceError(
        f"max_iter: the doubling algorithm did not converge to tol={tol if tol is not None else 'rounding level'} "
        f"in {max_iter} doublings")


def _dare(model, X0, max_iter):
    """scipy's DARE solver on the problem scaled to R of unit size: P solves the DARE of (Q, R) iff
    P / c solves that of (Q / c, R / c), and scipy's QZ reordering fails (or loses digits) when R is far
    from 1 (sigma_r = 1e7 m: "Reordering of (A, B) failed"; at 1e-6 m^2/s^3 and 1e7 m it was 3e-4 off
    the doubling algorithm's answer, scaled 2e-8).  Existence was checked before (PBH tests), so when
    the QZ method still fails (Q / R beyond ~1e40 either way: "Failed to find a finite solution") the
    problem is solvable but ill-conditioned for it: the doubling algorithm solves it instead."""
    c = float(np.abs(model.R).max())
    try:
        P = _sym(scipy.linalg.solve_discrete_are(model.F.T, model.H.T, model.Q / c, model.R / c) * c)
    except (np.linalg.LinAlgError, ValueError):
        return _doubling(model, None, max_iter, X0)
    # QZ can also "succeed" with a wrong answer on such problems (q = 1e-6, sigma_r = 1e20: P with a
    # negative diagonal of -4e39): a solution that is not PSD or not a fixed point is not accepted
    with np.errstate(all="ignore"):
        ok = np.all(np.isfinite(P)) and np.linalg.eigvalsh(P)[0] >= -1e-9 * np.abs(P).max() \
            and _residual(model, P) <= 1e-8
    return (P, 0) if ok else _doubling(model, None, max_iter, X0)


def _relf(model, P0, tol, max_iter):
    """Per-step RELF recursion Pe <- Pn + Fn [I + Pe On]^{-1} Pe Fn^T (Assimakis & Adam 2014, eq. 14)."""
    lp = lainiotis_parameters(model)
    eye = np.eye(model.n)
    return _iterate(lambda Pe: _sym(lp.Pn + lp.Fn @ np.linalg.solve(eye + Pe @ lp.On, Pe) @ lp.Fn.T),
                    P0, tol, max_iter, "the per-step Lainiotis Riccati recursion")


def steady_state(model: LinearGaussianModel, method: Method = "dare", *,
                 form: Literal["kalman", "lainiotis"] = "kalman", P0=None,
                 tol: float | None = None, max_iter: int = 100_000) -> SteadyState:
    """Steady-state gain, covariances and filter matrices of a model.

    Existence is checked first (detectable (F, H), no mode on the unit circle left undriven by Q).  When F
    has modes outside the unit circle that Q does not drive (F = 2, Q = 0) the stabilising solution still
    exists; the iterations then start from P0 = I (the default P0 only), since from 0 they stay on the
    non-stabilising solution.

    Parameters
    ----------
    model : LinearGaussianModel
        The model.
    method : {"dare", "doubling", "per-step"}, optional
        scipy's algebraic Riccati solver (on the problem scaled to R of unit size), the structure-preserving
        doubling algorithm, or the Riccati recursion step by step from P(0/0) = P0.
    form : {"kalman", "lainiotis"}, optional
        ``"kalman"``: A = (I - K H) F, B = K from the REKF solution (Assimakis & Adam 2014, eqs. 10-11);
        ``"lainiotis"``: Pe from the RELF recursion (eq. 14), A, B from eq. 13 (method "per-step" only).
    P0 : array_like, shape (n, n), optional
        Start of the iterative methods (default 0, or I as above).
    tol : float, optional
        Stopping rule of the iterative methods: None iterates to the rounding level; a number stops at the
        first relative step ||dP|| <= tol ||P||.  ``steady_state_time`` is the first step within 1e-13
        either way.
    max_iter : int, optional
        Largest number of iterations.

    Returns
    -------
    SteadyState
        P_pred, P_filt, K, A, B, the method, form and steady-state time.

    Raises
    ------
    NotDetectableError, NotStabilisableError
        No stabilising steady state exists (the message names the offending eigenvalues).
    ConvergenceError
        An iteration does not converge within ``max_iter``.
    NonFiniteError
        The model's magnitudes overflow the solver.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512

    Examples
    --------
    >>> from mptrack.models import assimakis_model_b
    >>> from mptrack.riccati import steady_state
    >>> ss = steady_state(assimakis_model_b())
    >>> ss.K.shape
    (2, 1)
    """
    require_model(model)
    if method not in METHODS:
        raise ParameterError(f"method: expected one of {METHODS}, got {method!r}")
    if form not in ("kalman", "lainiotis"):
        raise ParameterError(f"form: expected 'kalman' or 'lainiotis', got {form!r}")
    tol = None if tol is None else check_positive("tol", tol)
    max_iter = check_int("max_iter", max_iter, minimum=1)
    P0 = None if P0 is None else check_covariance("P0", P0, model.n)
    with one_blas_thread(model.n):   # few-by-few matrices: BLAS's threads would only spin afterwards
        _check_exists(model)
        try:
            with np.errstate(all="ignore"):
                ss = _solve(model, method, form, P0, tol, max_iter)
        except MptrackError:
            raise
        except (np.linalg.LinAlgError, ValueError, ZeroDivisionError) as exc:
            raise _overflow(f"the Riccati solution ({method})", dict(model=model, P0=P0), exc) from None
    require_finite(f"the Riccati solution ({method})", ss, model=model, P0=P0)
    return ss


def _solve(model, method, form, P0, tol, max_iter) -> SteadyState:
    n = model.n
    _, outside = undriven_modes(model.F, model.noise_factor())
    X0 = np.eye(n) * max(1.0, float(np.abs(model.R).max())) if outside else None
    if P0 is None:
        P0 = np.zeros((n, n)) if X0 is None else X0
    eye = np.eye(n)

    if form == "lainiotis":
        if method != "per-step":
            raise ParameterError("method: the Lainiotis form is solved with method='per-step' (RELF)")
        Pe, iters, ss_time = _relf(model, P0, tol, max_iter)
        lp = lainiotis_parameters(model)
        inv_term = np.linalg.solve((eye + Pe @ lp.On).T, lp.Fn.T).T  # Fn [I + Pe On]^{-1}
        A = inv_term
        B = lp.Kn + inv_term @ Pe @ lp.Km
        P_pred = _sym(model.Q + model.F @ Pe @ model.F.T)
        K, _ = _gain(model, P_pred)
        return SteadyState(K=K, P_pred=P_pred, P_filt=Pe, A=A, B=B, form=form, method=method,
                           iterations=iters, steady_state_time=ss_time,
                           residual=_residual(model, P_pred))

    if method == "dare":
        P_pred, iters = _dare(model, X0, max_iter)
        ss_time = None
    elif method == "doubling":
        P_pred, iters = _doubling(model, tol, max_iter, X0)
        ss_time = None
    else:
        P_pred, iters, ss_time = _per_step(model, P0, tol, max_iter)
    K, S = _gain(model, P_pred)
    P_filt = _sym(P_pred - K @ S @ K.T)
    A = (eye - K @ model.H) @ model.F
    return SteadyState(K=K, P_pred=P_pred, P_filt=P_filt, A=A, B=K.copy(), form=form,
                       method=method, iterations=iters, steady_state_time=ss_time,
                       residual=_residual(model, P_pred))
