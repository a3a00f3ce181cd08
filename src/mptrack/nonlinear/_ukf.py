"""The unscented Kalman filter (scaled unscented transform, angle-aware) and the unscented RTS smoother.

Discrete-time models (:class:`mptrack.models.NonlinearModel`): the sigma points of
N(x(k-1/k-1), P(k-1/k-1)) go through f, x(k/k-1) is their weighted mean and P(k/k-1)
their weighted covariance plus Q; the update draws new sigma points of the
prediction (as Stone Soup and Särkkä 2013 alg. 5.14 do).

Continuous-discrete models (:class:`ContinuousDiscreteModel`):

Prediction integrates the moment equations of the SDE with unscented
expectations (Särkkä 2007, IEEE TAC 52(10)):

    dm/dt = E[f(x)],   dP/dt = E[f(x)(x - m)^T] + E[(x - m) f(x)^T] + Q,

with classical RK4 sub-steps.  For a linear drift this is exactly the
Kalman prediction, so UKF ≡ KF on a linear model (a test pins it).  The
update uses the scaled unscented transform (Julier 2002; Wan & van der Merwe
2000); bearings are averaged on the circle and innovations are wrapped.
"""

from __future__ import annotations

import numpy as np

from .._validation import (
    as_real,
    as_vector,
    check_covariance,
    check_positive,
    finite_result,
)
from ..errors import ConvergenceError, NotPositiveDefiniteError, ParameterError
from ..linear import FilterResult
from ..models import NonlinearModel
from . import _named_kernels
from ._common import check_prior, prepare_nonlinear
from ._extended import _run, named_arguments, named_result, smooth_with
from ._model import ContinuousDiscreteModel

__all__ = ["ukf_filter", "ukf_smoother", "sigma_points"]

_LOG2PI = np.log(2.0 * np.pi)


def _weights(n: int, alpha: float, beta: float, kappa: float):
    lam = alpha * alpha * (n + kappa) - n
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = Wm[0] + 1.0 - alpha * alpha + beta
    return n + lam, Wm, Wc


def _sqrt(P: np.ndarray, what: str) -> np.ndarray:
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(0.5 * (P + P.T))
        if w[0] < -1e-9 * max(abs(w[-1]), 1e-300):
            raise NotPositiveDefiniteError(f"{what}: covariance lost positive semi-definiteness "
                                           f"(smallest eigenvalue {w[0]:.3g})") from None
        return V * np.sqrt(np.clip(w, 0.0, None))


def check_unscented(n: int, alpha, beta, kappa) -> dict:
    """Validated scaled-unscented-transform parameters: α > 0, β >= 0, n + κ > 0 (so (n + λ) > 0)."""
    alpha = check_positive("alpha", alpha)
    beta = check_positive("beta", beta, allow_zero=True)
    kappa = as_real("kappa", kappa)
    if n + kappa <= 0:
        raise ParameterError(f"kappa: expected a finite number with n + kappa > 0 (n = {n}), got {kappa!r}")
    return {"alpha": alpha, "beta": beta, "kappa": kappa}


@finite_result("the sigma points")
def sigma_points(m: np.ndarray, P: np.ndarray, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0):
    """The 2n+1 scaled sigma points of N(m, P) and their mean/covariance weights.

    Returns (X (2n+1, n), Wm (2n+1,), Wc (2n+1,)).  The defaults (α = 1, β = 2,
    κ = 0) keep every weight non-negative for n = 2, which keeps the
    propagated covariance PSD.
    """
    m = as_vector("m", m)
    P = check_covariance("P", P, m.shape[0])
    return _sigma_points(m, P, **check_unscented(m.shape[0], alpha, beta, kappa))


def _sigma_points(m: np.ndarray, P: np.ndarray, *, alpha: float, beta: float, kappa: float):
    """:func:`sigma_points` of validated arguments (the filters' inner step)."""
    n = m.shape[0]
    c, Wm, Wc = _weights(n, alpha, beta, kappa)
    S = _sqrt(c * P, "P")
    X = np.empty((2 * n + 1, n))
    X[0] = m
    X[1:n + 1] = m + S.T
    X[n + 1:] = m - S.T
    return X, Wm, Wc


def _circular_mean(model, Z: np.ndarray, Wm: np.ndarray) -> np.ndarray:
    zbar = Wm @ Z
    for i, period in enumerate(model.periods):
        if period is not None:
            ang = Z[:, i] * (2.0 * np.pi / period)
            zbar[i] = np.arctan2(Wm @ np.sin(ang), Wm @ np.cos(ang)) * (period / (2.0 * np.pi))
    return zbar


def _moment_rate(model, m, P, ut):
    X, Wm, Wc = _sigma_points(m, P, **ut)
    F = model.drift(X)
    dm = Wm @ F
    D = X - m
    C = (Wc[:, None] * F).T @ D
    return dm, C + C.T + model.Q


def ukf_predict(model: ContinuousDiscreteModel, m, P, *, substeps: int, ut: dict):
    """RK4 integration of the unscented moment equations over one dt."""
    h = model.dt / substeps
    for _ in range(substeps):
        k1 = _moment_rate(model, m, P, ut)
        k2 = _moment_rate(model, m + 0.5 * h * k1[0], P + 0.5 * h * k1[1], ut)
        k3 = _moment_rate(model, m + 0.5 * h * k2[0], P + 0.5 * h * k2[1], ut)
        k4 = _moment_rate(model, m + h * k3[0], P + h * k3[1], ut)
        m = m + (h / 6.0) * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
        P = P + (h / 6.0) * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
        P = 0.5 * (P + P.T)
    return m, P


def ukf_update(model, m, P, z, *, ut: dict, k: int = 0):
    """Unscented measurement update; NaN components of z are skipped.  Returns (m, P, loglik)."""
    ok = ~np.isnan(z)
    if not ok.any():
        return m, P, 0.0
    X, Wm, Wc = _sigma_points(m, P, **ut)
    if isinstance(model, NonlinearModel):
        Z, R = model.h(X), model.R_at(m, k)
    else:
        Z, R = model.measurement(X), model.R
    zbar = _circular_mean(model, Z, Wm)
    dZ = model.innovation(Z, zbar)[:, ok]
    D = X - m
    R = R[np.ix_(ok, ok)]
    S = (Wc[:, None] * dZ).T @ dZ + R
    C = (Wc[:, None] * D).T @ dZ
    nu = model.innovation(z, zbar)[ok]
    L = np.linalg.cholesky(S)
    K = np.linalg.solve(S, C.T).T
    m = m + K @ nu
    P = P - K @ S @ K.T
    P = 0.5 * (P + P.T)
    w = np.linalg.solve(L, nu)
    ll = -0.5 * (w @ w + 2.0 * np.log(np.diag(L)).sum() + ok.sum() * _LOG2PI)
    return m, P, float(ll)


def _unscented_prediction(model: NonlinearModel, x, P, k: int, ut: dict):
    """(x(k/k-1), P(k/k-1), cross-covariance of x(k-1) and x(k)) by the unscented transform through f."""
    X, Wm, Wc = _sigma_points(x, P, **ut)
    Y = model.f(X)
    m = Wm @ Y
    dY = Y - m
    Pp = (Wc[:, None] * dY).T @ dY + model.Q_at(x, k)
    return m, 0.5 * (Pp + Pp.T), (Wc[:, None] * (X - x)).T @ dY


@finite_result("the UKF")
def ukf_filter(model, z, x0, P0, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
               substeps: int | None = None, prior: str = "initial") -> FilterResult:
    """UKF over measurements z (T, m) from the prior N(x0, P0), for a discrete-time
    :class:`~mptrack.models.NonlinearModel` or a :class:`ContinuousDiscreteModel` (module docstring).

    alpha, beta, kappa   scaled unscented transform parameters (α > 0, β >= 0, n + κ > 0); the
                         defaults α = 1, β = 2, κ = 0 keep every weight non-negative.  FilterPy's
                         MerweScaledSigmaPoints(n, alpha, beta, kappa) and Stone Soup's
                         UnscentedKalmanPredictor(alpha=.., beta=.., kappa=..) use the same points.
    substeps             continuous-discrete models: RK4 sub-steps of the moment equations per dt
                         (default model.substeps)
    prior                "initial" (x0, P0 at time 0) or "first-measurement" (NonlinearModel only)
    NaN measurement components are skipped; a NaN row only predicts.  A
    :func:`~mptrack.models.nonlinear_model` of a linear motion and named measurement models runs
    compiled with the same numbers.
    Raises ConvergenceError when the moment equations blow up (stiff drift,
    far from the sigma points) and NotPositiveDefiniteError when P loses PSD.
    """
    z, x, P, substeps = prepare_nonlinear(model, z, x0, P0, substeps)
    ut = check_unscented(model.n, alpha, beta, kappa)
    if isinstance(model, NonlinearModel) and model.named is not None:
        first = check_prior(prior)
        c, Wm, Wc = _weights(model.n, **ut)
        out = _named_kernels.ukf_named(*named_arguments(model), z, x, P, first, c, Wm, Wc)
        if out[0] == _named_kernels.OK:
            return named_result(out, x, P, first, "UKF")
    if isinstance(model, NonlinearModel):
        predict = lambda mdl, x, P, k: _unscented_prediction(mdl, x, P, k, ut)[:2]
        update = lambda mdl, x, P, z, k: ukf_update(mdl, x, P, z, ut=ut, k=k)
        return _run(model, z, x, P, prior, predict, update, "UKF")
    if prior != "initial":
        raise ParameterError("prior: a ContinuousDiscreteModel's prior is at t = 0 (prior='initial')")
    x0, P0 = x, P
    T, n = z.shape[0], model.n
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    xp, Pp = np.empty((T, n)), np.empty((T, n, n))
    loglik = 0.0
    for k in range(T):
        try:
            with np.errstate(over="raise", invalid="raise"):
                x, P = ukf_predict(model, x, P, substeps=substeps, ut=ut)
                xp[k], Pp[k] = x, P
                x, P, ll = ukf_update(model, x, P, z[k], ut=ut)
        except (FloatingPointError, np.linalg.LinAlgError) as exc:
            raise ConvergenceError(f"UKF diverged at measurement {k} ({exc})") from None
        xs[k], Ps[k] = x, P
        loglik += ll
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=loglik, method="UKF", x0=x0, P0=P0)


@finite_result("the unscented RTS smoother")
def ukf_smoother(model: NonlinearModel, result: FilterResult, *, alpha: float = 1.0, beta: float = 2.0,
                 kappa: float = 0.0) -> FilterResult:
    """Unscented RTS smoother (Särkkä 2008, IEEE TAC 53(3)) on :func:`ukf_filter`'s result for a
    NonlinearModel, with the filter's sigma-point parameters: C(k) = D(k) P(k+1/k)^-1 with D the
    unscented cross-covariance of x(k) and x(k+1).  x(0/T), P(0/T) are x0, P0 (method "URTS")."""
    if not isinstance(model, NonlinearModel):
        raise ParameterError(f"model: expected a NonlinearModel, got {type(model).__name__}")
    ut = check_unscented(model.n, alpha, beta, kappa)
    return smooth_with(model, result, lambda mdl, x, P, k: _unscented_prediction(mdl, x, P, k, ut)[2], "URTS")
