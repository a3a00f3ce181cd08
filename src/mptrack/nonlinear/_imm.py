"""The interacting multiple model (IMM) filter (Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan
2001, sec. 11.6.6) over any set of models of the same state, each run as an EKF (exact Kalman steps
for linear models).

Per measurement k, with the Markov mode transition matrix Π (Π[i, j] = P(mode j at k | mode i at k-1)):

    c_j = Σ_i Π[i, j] μ_i,   μ_{i|j} = Π[i, j] μ_i / c_j                               (mixing)
    x0_j = Σ_i μ_{i|j} x_i,  P0_j = Σ_i μ_{i|j} (P_i + (x_i - x0_j)(x_i - x0_j)^T)
    x_j, P_j, Λ_j = EKF step of model j from (x0_j, P0_j)                              (mode-matched)
    μ_j = Λ_j c_j / Σ_l Λ_l c_l,   x = Σ_j μ_j x_j,   P = Σ_j μ_j (P_j + (x_j - x)(x_j - x)^T)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._core.filter_inputs import check_prior, prepare_nonlinear
from .._core.finiteness import finite_result, require_finite
from .._core.validation import as_matrix, as_real, as_vector, check_positive
from ..errors import ParameterError, ShapeError
from ..result import FilterResult
from ..models import LinearGaussianModel, MeasurementModel, NonlinearModel, constant_acceleration
from ._extended import ekf_predict, ekf_update

__all__ = ["IMMResult", "imm_filter", "cv_ca_models"]


@dataclass(frozen=True, eq=False)
class IMMResult(FilterResult):
    """A FilterResult (the combined estimate) with the mode probabilities mu (T, r) after each update and
    the mode-matched means x_modes (T, r, n)."""

    mu: np.ndarray | None = None
    x_modes: np.ndarray | None = None


def _as_nonlinear(model, name: str) -> NonlinearModel:
    if isinstance(model, NonlinearModel):
        return model
    if isinstance(model, LinearGaussianModel):
        F, H = model.F, model.H
        Ft, Ht = F.T.copy(), H.T.copy()
        return NonlinearModel(lambda X: X @ Ft, lambda X: X @ Ht, model.Q, model.R, jac_f=lambda x: F,
                              jac_h=lambda x: H, name=model.name)
    raise ParameterError(f"{name}: expected a NonlinearModel or LinearGaussianModel, got {type(model).__name__}")


def _transition(transition, r: int) -> np.ndarray:
    Pi = as_matrix("transition", transition, r, r)
    if np.any(Pi < 0) or not np.allclose(Pi.sum(axis=1), 1.0, rtol=0, atol=1e-12):
        raise ParameterError("transition: expected a row-stochastic matrix (entries >= 0, rows summing to 1)")
    return Pi


@finite_result("the IMM")
def imm_filter(models, z, x0, P0, transition, *, mu0=None, prior: str = "initial") -> IMMResult:
    """Interacting multiple model (IMM) filter; with one model it is the EKF (the KF for a linear model).

    Parameters
    ----------
    models : sequence of NonlinearModel or LinearGaussianModel
        The modes, with the same state and measurement.
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped, a NaN row only predicts.
    x0 : array_like, shape (n,)
        The prior mean, required.
    P0 : array_like, shape (n, n)
        The prior covariance, required.
    transition : array_like, shape (r, r)
        The Markov transition matrix of the modes (rows sum to 1).
    mu0 : array_like, shape (r,), optional
        Initial mode probabilities (default uniform).
    prior : {"initial", "first-measurement"}, optional
        x0, P0, mu0 at time 0, or at the first measurement (no prediction and no mode transition before it).

    Returns
    -------
    IMMResult
        The combined estimates (method "IMM"), mode probabilities ``mu`` and per-mode means ``x_modes``.

    References
    ----------
    .. [1] H. A. P. Blom and Y. Bar-Shalom, "The interacting multiple model algorithm for systems with Markovian
           switching coefficients", IEEE Transactions on Automatic Control, vol. 33, no. 8, pp. 780–783, 1988.
           doi:10.1109/9.1299
    """
    models = [_as_nonlinear(m, f"models[{i}]") for i, m in enumerate(models)] if not isinstance(
        models, (NonlinearModel, LinearGaussianModel)) else [_as_nonlinear(models, "models")]
    if not models:
        raise ParameterError("models: expected at least one model")
    first = models[0]
    for i, mdl in enumerate(models[1:], 1):
        if (mdl.n, mdl.m) != (first.n, first.m):
            raise ShapeError(f"models[{i}]: (n, m) = {(mdl.n, mdl.m)} differs from models[0]'s {(first.n, first.m)}")
    r = len(models)
    Pi = _transition(transition, r)
    z, x0, P0, _ = prepare_nonlinear(first, z, x0, P0, kinds=(NonlinearModel,))
    at_first = check_prior(prior)
    given = {"z": z, "x0": x0, "P0": P0}
    mu = np.full(r, 1.0 / r) if mu0 is None else as_vector("mu0", mu0, r)
    if np.any(mu < 0) or abs(mu.sum() - 1.0) > 1e-12:
        raise ParameterError("mu0: expected mode probabilities (>= 0, summing to 1)")
    T, n = z.shape[0], first.n
    xs, Ps, xp, Pp = np.empty((T, n)), np.empty((T, n, n)), np.empty((T, n)), np.empty((T, n, n))
    mus, xm = np.empty((T, r)), np.empty((T, r, n))
    X = np.repeat(x0[None], r, 0)
    P = np.repeat(P0[None], r, 0)
    loglik = 0.0
    for k in range(T):
        predict = not (at_first and k == 0)
        if predict:
            c = mu @ Pi                                                # (r,)
            W = Pi * mu[:, None] / np.where(c > 0, c, 1.0)[None, :]    # W[i, j] = mu_{i|j}
            X0 = W.T @ X
            D = X[:, None, :] - X0[None, :, :]                         # (i, j, n)
            P0m = np.einsum("ij,iab->jab", W, P) + np.einsum("ij,ija,ijb->jab", W, D, D)
        else:                                                          # the prior is at this measurement
            c, X0, P0m = mu, X.copy(), P.copy()
        lls = np.empty(r)
        pred_x, pred_P = np.empty((r, n)), np.empty((r, n, n))
        for j, mdl in enumerate(models):
            if predict:
                ekf_predict(mdl, X0[j], P0m[j], k, pred_x[j], pred_P[j])
            else:
                pred_x[j], pred_P[j] = X0[j], P0m[j]
            lls[j] = ekf_update(mdl, pred_x[j], pred_P[j], z, k, "IMM", given, X[j], P[j])
        with np.errstate(divide="ignore"):
            a = lls + np.log(c)
        top = a.max()
        weights = np.exp(a - top)
        loglik += top + np.log(weights.sum())
        mu = weights / weights.sum()
        xs[k] = mu @ X
        d = X - xs[k]
        Ps[k] = np.einsum("j,jab->ab", mu, P) + (mu[:, None] * d).T @ d
        xp[k] = c @ pred_x
        dp = pred_x - xp[k]
        Pp[k] = np.einsum("j,jab->ab", c, pred_P) + (c[:, None] * dp).T @ dp
        mus[k], xm[k] = mu, X
    require_finite("the IMM", (xs, Ps), **given)
    return IMMResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="IMM",
                     x0=None if at_first else x0, P0=None if at_first else P0, mu=mus, x_modes=xm)


@finite_result("the CV/CA models")
def cv_ca_models(dt: float, q_cv: float, q_ca: float, measurement: MeasurementModel, *, axes: int = 2,
                 p_stay: float = 0.95):
    """The two-model CV/CA manoeuvre tracker for :func:`imm_filter`, on the CA state
    [x, vx, ax, y, vy, ay(, z, vz, az)].

    Mode 0 is constant velocity (the acceleration held at 0), mode 1 constant acceleration.

    Parameters
    ----------
    dt : float
        Sampling interval (s).
    q_cv : float
        White-acceleration density of mode 0 (m^2/s^3).
    q_ca : float
        White-jerk density of mode 1 (m^2/s^5).
    measurement : MeasurementModel
        Built with position=(0, 3[, 6]) and, for range rate, velocity=(1, 4[, 7]).
    axes : int, optional
        2 or 3.
    p_stay : float, optional
        Probability of staying in a mode.

    Returns
    -------
    models : list of NonlinearModel
    transition : ndarray, shape (2, 2)
        [[p, 1 - p], [1 - p, p]] with p = p_stay.

    References
    ----------
    .. [1] H. A. P. Blom and Y. Bar-Shalom, "The interacting multiple model algorithm for systems with Markovian
           switching coefficients", IEEE Transactions on Automatic Control, vol. 33, no. 8, pp. 780–783, 1988.
           doi:10.1109/9.1299
    .. [2] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    """
    if not 0.0 < as_real("p_stay", p_stay) < 1.0:
        raise ParameterError(f"p_stay: expected a probability in (0, 1), got {p_stay!r}")
    if not isinstance(measurement, MeasurementModel):
        raise ParameterError(f"measurement: expected a MeasurementModel, got {type(measurement).__name__}")
    dt, q_cv = check_positive("dt", dt), check_positive("q_cv", q_cv, allow_zero=True)
    ca = constant_acceleration(dt, q_ca, axes=axes)
    cv1 = np.array([[1.0, dt, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    q1 = q_cv * np.array([[dt ** 3 / 3, dt ** 2 / 2, 0.0], [dt ** 2 / 2, dt, 0.0], [0.0, 0.0, 0.0]])
    F_cv, Q_cv = np.kron(np.eye(axes), cv1), np.kron(np.eye(axes), q1)
    models = []
    for F, Q, name in ((F_cv, Q_cv, "CV"), (ca.F, ca.Q, "CA")):
        Ft = F.T.copy()
        models.append(NonlinearModel(lambda X, Ft=Ft: X @ Ft, measurement.h, Q, measurement.R,
                                     jac_f=lambda x, F=F: F, jac_h=measurement.jac_h,
                                     angle_components=measurement.angle_components, dt=dt, name=name))
    return models, np.array([[p_stay, 1.0 - p_stay], [1.0 - p_stay, p_stay]])
