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

Sub-steps follow the drift: at each step the rate rho of the drift (the
largest row sum of |df/dx| at the sigma points of the prior, by forward
differences) sets h <= 0.25 / rho.  RK4's local error then stays near
(h rho)^5 / 120 ~ 1e-5 of the state's change per sub-step: on eq. 42 (Van der
Pol, Zhao, Chen & Ma 2013) that is 4-13 sub-steps per second where a fixed 20
were used, and the estimates move by ~1e-5, against a filter error of 0.36.
A model with compiled kernels (``zhao2013_model``, ``linear_sde_model``, or
``kernels=BlockKernels(...)``) runs the whole filter compiled
(:func:`mptrack.nonlinear._kernels.cd_ukf_run`), with the NumPy path's
arithmetic (pinned to 1e-10 by a test) and about a hundred times faster.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_vector, check_covariance, check_positive, finite_result
from ..errors import ConvergenceError, NotPositiveDefiniteError, ParameterError
from ..linear import FilterResult
from ..continuous import _kernels as kern
from ..continuous._model import ContinuousDiscreteModel
from ..models import NonlinearModel
from . import _named_kernels
from ._common import check_prior, prepare_nonlinear
from . import _step_kernels as steps
from ._extended import _run, check_step, named_arguments, named_result, smooth_with, user_array

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
    if isinstance(kappa, bool) or not np.isfinite(np.asarray(kappa, dtype=float)) or n + float(kappa) <= 0:
        raise ParameterError(f"kappa: expected a finite number with n + kappa > 0 (n = {n}), got {kappa!r}")
    return {"alpha": alpha, "beta": beta, "kappa": float(kappa)}


@finite_result("the sigma points")
def sigma_points(m: np.ndarray, P: np.ndarray, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0):
    """The 2n+1 scaled sigma points of N(m, P) and their mean/covariance weights.

    Returns (X (2n+1, n), Wm (2n+1,), Wc (2n+1,)).  The defaults (α = 1, β = 2,
    κ = 0) keep every weight non-negative for n = 2, which keeps the
    propagated covariance PSD.
    """
    m = as_vector("m", m)
    n = m.shape[0]
    P = check_covariance("P", P, n)
    alpha, beta, kappa = check_unscented(n, alpha, beta, kappa).values()
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
    X, Wm, Wc = sigma_points(m, P, **ut)
    F = model.drift(X)
    dm = Wm @ F
    D = X - m
    C = (Wc[:, None] * F).T @ D
    return dm, C + C.T + model.Q


def drift_substeps(model: ContinuousDiscreteModel, m, P, ut: dict) -> int:
    """Sub-steps over dt for the drift's rate at the sigma points of N(m, P) (module docstring; the
    compiled twin is ``_kernels.drift_rate`` / ``substeps_for``)."""
    X, _, _ = sigma_points(m, P, **ut)
    N, n = X.shape
    Xd = np.repeat(X[:, None, :], n + 1, axis=1)
    for i in range(n):
        Xd[:, 1 + i, i] += 1e-6 * (1.0 + np.abs(X[:, i]))
    Fd = np.asarray(model.drift(Xd.reshape(-1, n)), dtype=float).reshape(N, n + 1, n)
    step = np.stack([Xd[:, 1 + i, i] - X[:, i] for i in range(n)], axis=1)  # (N, n)
    rows = np.zeros((N, n))
    for i in range(n):
        rows += np.abs(Fd[:, 1 + i, :] - Fd[:, 0, :]) / step[:, i:i + 1]
    rho = float(rows.max())
    if not rho < np.inf:
        return kern.MAX_SUBSTEPS
    return min(max(int(np.ceil(model.dt * rho / kern.RATE_STEP)), 1), kern.MAX_SUBSTEPS)


def ukf_predict(model: ContinuousDiscreteModel, m, P, *, substeps: int | None, ut: dict):
    """RK4 integration of the unscented moment equations over one dt (``substeps`` None: by the drift's
    rate, :func:`drift_substeps`)."""
    if substeps is None:
        substeps = drift_substeps(model, m, P, ut)
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
    X, Wm, Wc = sigma_points(m, P, **ut)
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


def _points(x, P, c: float, X=None) -> np.ndarray:
    """The sigma points of N(x, P) with scale c = n + λ (no validation: the filters' inner loop), into X
    when given: the compiled Cholesky factor, or the eigenvalue square root of a semi-definite P."""
    X = np.empty((2 * x.shape[0] + 1, x.shape[0])) if X is None else X
    if steps.sigma_into(x, P, c, X):
        return X
    S = _sqrt(c * P, "P")
    return np.concatenate([x[None], x + S.T, x - S.T])


def _unscented_predict(model: NonlinearModel, x, P, k: int, sp: tuple, x_out, P_out) -> None:
    """x(k/k-1), P(k/k-1) into x_out, P_out by the unscented transform of N(x, P) through f, plus Q(x, k);
    sp = (c, Wm, Wc, X) with X a (2n+1, n) work array for the sigma points."""
    c, Wm, Wc, X = sp
    n = model.n
    Y = user_array(model.f(_points(x, P, c, X)), (2 * n + 1, n), "f", k)
    steps.unscented_moments_into(Y, Wm, Wc, model.Q_at(x, k), x_out, P_out)


def _unscented_cross(model: NonlinearModel, x, P, sp: tuple) -> np.ndarray:
    """The cross-covariance of x(k) ~ N(x, P) and f(x(k)) by the unscented transform (the URTS's D(k))."""
    c, Wm, Wc = sp
    X = _points(x, P, c)
    Y = model.f(X)
    return (Wc[:, None] * (X - x)).T @ (Y - Wm @ Y)


def _unscented_update(model: NonlinearModel, x, P, z, k: int, sp: tuple, method: str, inputs: dict,
                      x_out, P_out) -> float:
    """The unscented update with row k of z and the sigma points of N(x(k/k-1), P(k/k-1)) through h,
    into x_out, P_out."""
    c, Wm, Wc, X = sp
    X = _points(x, P, c, X)
    Z = user_array(model.h(X), (X.shape[0], model.m), "h", k)
    R = model.R_at(x, k)
    status, ll = steps.ukf_update_into(x, P, X, Z, Wm, Wc, R, z, k, model.period_array, x_out, P_out)
    if status != steps.OK:
        check_step(status, method, k, x, P, {"h": Z, "R": R}, inputs)
    return ll


def _cd_ukf_compiled(model: ContinuousDiscreteModel, z, x0, P0, substeps, ut):
    """The compiled continuous-discrete UKF, or None when a step needs the NumPy path (a semi-definite
    square root, an error to raise)."""
    compiled = kern.compiled_model(model)
    T, n = z.shape[0], model.n
    c, Wm, Wc = _weights(n, **ut)
    xs, xp, Ps, Pp = np.empty((T, n)), np.empty((T, n)), np.empty((T, n, n)), np.empty((T, n, n))
    status, _, loglik = kern.cd_ukf_run(
        z, x0, P0, model.dt, 0 if substeps is None else substeps, *compiled.drift_at,
        model.kernels.drift_params, *compiled.measurement_at, model.kernels.measurement_params, compiled.periods,
        np.asarray(model.Q, dtype=float), np.asarray(model.R, dtype=float), c, Wm, Wc, xs, Ps, xp, Pp,
        np.empty(T, np.int64))
    if status != _named_kernels.OK:
        return None
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="UKF", x0=x0, P0=P0,
                        inputs=ut)


@finite_result("the UKF")
def ukf_filter(model, z, x0, P0, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
               substeps: int | None = None, prior: str = "initial", compiled: bool | None = None) -> FilterResult:
    """UKF over measurements z (T, m) from the prior N(x0, P0), for a discrete-time
    :class:`~mptrack.models.NonlinearModel` or a :class:`ContinuousDiscreteModel` (module docstring).

    alpha, beta, kappa   scaled unscented transform parameters (α > 0, β >= 0, n + κ > 0); the
                         defaults α = 1, β = 2, κ = 0 keep every weight non-negative.  FilterPy's
                         MerweScaledSigmaPoints(n, alpha, beta, kappa) and Stone Soup's
                         UnscentedKalmanPredictor(alpha=.., beta=.., kappa=..) use the same points.
    substeps             continuous-discrete models: RK4 sub-steps of the moment equations per dt;
                         None (default): chosen at each step by the drift's rate (module docstring)
    prior                "initial" (x0, P0 at time 0) or "first-measurement" (NonlinearModel only)
    compiled             continuous-discrete models with compiled kernels: None/True run compiled,
                         False the NumPy path (same numbers)
    NaN measurement components are skipped; a NaN row only predicts.  A
    :func:`~mptrack.models.nonlinear_model` of a linear motion and named measurement models runs
    compiled with the same numbers.
    Raises ConvergenceError when the moment equations blow up (stiff drift,
    far from the sigma points) and NotPositiveDefiniteError when P loses PSD.
    """
    adaptive = substeps is None
    z, x, P, substeps = prepare_nonlinear(model, z, x0, P0, substeps)
    substeps = None if adaptive else substeps
    ut = check_unscented(model.n, alpha, beta, kappa)
    if isinstance(model, NonlinearModel):
        first = check_prior(prior)
        sp = _weights(model.n, **ut)
        if model.named is not None:
            out = _named_kernels.ukf_named(*named_arguments(model), z, x, P, first, *sp)
            if out[0] == _named_kernels.OK:
                return named_result(out, x, P, first, "UKF", inputs=ut)
        work = sp + (np.empty((2 * model.n + 1, model.n)),)

        def predict(mdl, x, P, k, x_out, P_out):
            _unscented_predict(mdl, x, P, k, work, x_out, P_out)

        def update(mdl, x, P, z, k, method, given, x_out, P_out):
            return _unscented_update(mdl, x, P, z, k, work, method, given, x_out, P_out)
        return _run(model, z, x, P, prior, predict, update, "UKF", inputs=ut)
    if prior != "initial":
        raise ParameterError("prior: a ContinuousDiscreteModel's prior is at t = 0 (prior='initial')")
    if compiled and model.kernels is None:
        raise ParameterError("compiled: the model has no compiled kernels (BlockKernels)")
    if model.kernels is not None and compiled is not False:
        result = _cd_ukf_compiled(model, z, x, P, substeps, ut)
        if result is not None:
            return result
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
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=loglik, method="UKF", x0=x0, P0=P0, inputs=ut)


def ukf_smoother(model: NonlinearModel, result: FilterResult, *, alpha: float | None = None,
                 beta: float | None = None, kappa: float | None = None) -> FilterResult:
    """Unscented RTS smoother (Särkkä 2008, IEEE TAC 53(3)) on :func:`ukf_filter`'s result for a
    NonlinearModel: C(k) = D(k) P(k+1/k)^-1 with D the unscented cross-covariance of x(k) and x(k+1).
    x(0/T), P(0/T) are x0, P0 (method "URTS").

    The sigma points must be the filter's (D is paired with the filter's P(k+1/k)): they are read from
    the result (``result.inputs``); alpha, beta, kappa may be omitted, and values other than the
    filter's raise a ParameterError.  For a result that does not record them (not from ukf_filter)
    they default to α = 1, β = 2, κ = 0."""
    if not isinstance(model, NonlinearModel):
        raise ParameterError(f"model: expected a NonlinearModel, got {type(model).__name__}")
    given = {"alpha": alpha, "beta": beta, "kappa": kappa}
    recorded = result.inputs if isinstance(result, FilterResult) and result.inputs else {}
    ut = {"alpha": 1.0, "beta": 2.0, "kappa": 0.0}
    for name, value in given.items():
        if name in recorded:
            ut[name] = recorded[name]
            if value is not None and value != recorded[name]:
                raise ParameterError(f"{name}: the filter ran with {name} = {recorded[name]!r}, got {value!r}; "
                                     f"the smoother needs the filter's sigma points (omit {name})")
        elif value is not None:
            ut[name] = value
    sp = _weights(model.n, **check_unscented(model.n, **ut))
    return smooth_with(model, result, lambda mdl, x, P: _unscented_cross(mdl, x, P, sp), "URTS")
