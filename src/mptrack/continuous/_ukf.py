"""The unscented Kalman filter on a continuous-discrete model (Särkkä 2007): the prediction integrates the
moment equations of the SDE with unscented expectations,

    dm/dt = E[f(x)],   dP/dt = E[f(x)(x - m)^T] + E[(x - m) f(x)^T] + Q,

with classical RK4 sub-steps, the update is the scaled unscented transform with bearings averaged on the
circle.  :func:`mptrack.nonlinear.ukf_filter` runs it for a :class:`ContinuousDiscreteModel` (its module
docstring has the choice of sub-steps); a model with compiled kernels runs the whole filter compiled
(:func:`._kernels.cd_ukf_run`) with the same arithmetic.
"""

from __future__ import annotations

import numpy as np

from .._core.kalman import OK, unscented_update
from .._core.unscented import sigma_points, sigma_points_unchecked, weights
from ..errors import ConvergenceError, ParameterError
from ..result import FilterResult, innovation_arrays
from . import _kernels as kern
from ._model import ContinuousDiscreteModel

__all__ = ["cd_ukf", "drift_substeps", "ukf_predict", "ukf_update"]


def _moment_rate(model, m, P, ut):
    X, Wm, Wc = sigma_points_unchecked(m, P, **ut)
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


def ukf_update(model: ContinuousDiscreteModel, m, P, z, *, ut: dict):
    """Unscented measurement update (the compiled Kalman core's :func:`unscented_update`, bearings averaged
    on the circle); NaN components of z are skipped.  Returns (m, P, loglik, innovation (m,), S (m, m)),
    the innovation and S NaN for the components not used; an S without a Cholesky factor raises
    LinAlgError."""
    nu, S, nis = innovation_arrays((1,), z.shape[0])
    X, Wm, Wc = sigma_points_unchecked(m, P, **ut)
    Z = np.array(model.measurement(X), dtype=float)
    periods = np.array([0.0 if p is None else p for p in model.periods])
    status, m, P, ll = unscented_update(np.array(m, dtype=float), np.array(P, dtype=float), X, Z, Wm, Wc,
                                        np.asarray(model.R, dtype=float), z[None], 0, periods, nu, S, nis, 0)
    if status != OK:
        raise np.linalg.LinAlgError("the innovation covariance is not positive definite")
    return m, P, float(ll), nu[0], S[0]


def _cd_ukf_compiled(model: ContinuousDiscreteModel, z, x0, P0, substeps, ut):
    """The compiled continuous-discrete UKF, or None when a step needs the NumPy path (a semi-definite
    square root, an error to raise)."""
    compiled = kern.compiled_model(model)
    T, n = z.shape[0], model.n
    c, Wm, Wc = weights(n, **ut)
    xs, xp, Ps, Pp = np.empty((T, n)), np.empty((T, n)), np.empty((T, n, n)), np.empty((T, n, n))
    nu, S, nis = innovation_arrays((T,), model.m)
    status, _, loglik = kern.cd_ukf_run(
        z, x0, P0, model.dt, 0 if substeps is None else substeps, *compiled.drift_at,
        model.kernels.drift_params, *compiled.measurement_at, model.kernels.measurement_params, compiled.periods,
        np.asarray(model.Q, dtype=float), np.asarray(model.R, dtype=float), c, Wm, Wc, xs, Ps, xp, Pp, nu, S,
        nis, np.empty(T, np.int64))
    if status != kern.OK:
        return None
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="UKF", x0=x0, P0=P0,
                        inputs=ut, innovation=nu, S=S, nis=nis)


def cd_ukf(model: ContinuousDiscreteModel, z, x, P, *, substeps, ut: dict, prior: str, compiled) -> FilterResult:
    """The UKF of :func:`mptrack.nonlinear.ukf_filter` on a continuous-discrete model, from validated
    arguments (z (T, m), prior x, P at t = 0, ``substeps`` None: by the drift's rate, unscented
    parameters ``ut``): compiled when the model has kernels, else the moment equations in NumPy."""
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
    nu, S, _ = innovation_arrays((T,), model.m)
    loglik = 0.0
    for k in range(T):
        try:
            with np.errstate(over="raise", invalid="raise"):
                x, P = ukf_predict(model, x, P, substeps=substeps, ut=ut)
                xp[k], Pp[k] = x, P
                x, P, ll, nu[k], S[k] = ukf_update(model, x, P, z[k], ut=ut)
        except (FloatingPointError, np.linalg.LinAlgError) as exc:
            raise ConvergenceError(f"UKF diverged at measurement {k} ({exc})") from None
        xs[k], Ps[k] = x, P
        loglik += ll
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=loglik, method="UKF", x0=x0, P0=P0, inputs=ut,
                        innovation=nu, S=S)
