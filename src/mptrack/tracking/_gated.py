"""Kalman filtering of position fixes at irregular times, with NIS gating, and its RTS smoother.

For every interval dt(k) = t(k) - t(k-1) the continuous motion model is
discretised exactly (F = e^{Phi dt}, Q by Van Loan's method, seed 001 sec. 2;
:func:`mptrack.models.van_loan`), so gaps need no special case: a long interval
simply predicts further and the covariance grows.

Outlier gating uses the normalised innovation squared (NIS)

    eps(k) = nu(k)^T S(k)^{-1} nu(k),   nu = z - H x(k/k-1),   S = H P(k/k-1) H^T + R(k),

which for a consistent filter is chi-square with m = dim z degrees of freedom
(Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4).  A measurement whose NIS exceeds
the chi-square quantile ``gate_probability`` (default 0.999: 13.82 for a 2-D
fix) is rejected: the step only predicts and the point is flagged "outlier".
After ``max_rejections`` consecutive rejections that agree with each other (a
least-squares straight line through them leaves every residual inside the gate)
the filter re-initialises from that line, position and velocity at the last of
them (flag "reset"), so a manoeuvre or a long gap cannot lose the track while
scattered outliers never re-initialise it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.stats

from .._validation import as_array, as_sequence, as_vector, check_covariance, check_int
from ..errors import ParameterError, ShapeError
from ..linear import FilterResult, kalman_step
from ..models import ContinuousLinearModel, van_loan

__all__ = ["transitions", "GatedResult", "kalman_filter_gated", "rts_smoother_irregular", "nis_threshold", "FLAGS"]

#: Per-point flags of a tracking result.
FLAGS = ("update", "outlier", "predicted", "reset")


def nis_threshold(probability: float, dof: int) -> float:
    """Chi-square quantile: the NIS gate that a consistent filter passes with ``probability``."""
    if not 0.0 < probability < 1.0:
        raise ParameterError(f"gate_probability: expected a probability in (0, 1), got {probability!r}")
    return float(scipy.stats.chi2.ppf(probability, dof))


def transitions(model: ContinuousLinearModel, dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F (T, n, n), Q (T, n, n)) of ``model`` over each interval dts[k] >= 0 seconds (Van Loan).

    For the integrator chains of the CV/CA models Phi is nilpotent, and so is
    Van Loan's block matrix M = [[-Phi, L Qc L^T], [0, Phi^T]]; e^{M dt} is
    then the finite sum of (M dt)^j / j!, j < 2n, evaluated for all intervals
    at once (exact, and ~1000x faster than one expm per interval).  Other
    models fall back to :func:`mptrack.models.van_loan` per distinct interval.
    """
    n = model.n
    dts = np.asarray(dts, dtype=float)
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -model.Phi
    M[:n, n:] = model.L @ model.Qc @ model.L.T
    M[n:, n:] = model.Phi.T
    powers = [np.eye(2 * n)]
    for _ in range(2 * n):
        powers.append(powers[-1] @ M)
    if np.allclose(powers[-1], 0.0, atol=0.0):
        coef = np.stack([dts ** j / np.prod(np.arange(1, j + 1)) for j in range(2 * n)], axis=1)  # (T, 2n)
        E = np.einsum("tj,jab->tab", coef, np.stack(powers[:-1]))
        F = E[:, n:, n:].transpose(0, 2, 1)
        Q = F @ E[:, :n, n:]
    else:
        cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        for dt in np.unique(dts):
            cache[float(dt)] = van_loan(model.Phi, model.L, model.Qc, dt)
        F = np.stack([cache[float(dt)][0] for dt in dts])
        Q = np.stack([cache[float(dt)][1] for dt in dts])
    return F, 0.5 * (Q + Q.transpose(0, 2, 1))


@dataclass(frozen=True, eq=False)
class GatedResult:
    """A gated irregular-time KF run: ``result`` (FilterResult) plus per-step data.

    nis   (T,) NIS of each measurement (NaN where there was none)
    flag  (T,) index into FLAGS: 0 update, 1 outlier (rejected), 2 predicted (no measurement), 3 reset
    F, Q  (T, n, n) the transition used to reach step k from step k-1 (for smoothing)
    """

    result: FilterResult
    nis: np.ndarray
    flag: np.ndarray
    F: np.ndarray
    Q: np.ndarray


def kalman_filter_gated(model: ContinuousLinearModel, times, z, x0, P0, *, t0: float | None = None, R=None,
                        gate_probability: float | None = 0.999, max_rejections: int = 3,
                        reset_P0=None) -> GatedResult:
    """Kalman filter at irregular times with NIS outlier gating (see the module doc).

    model    ContinuousLinearModel (e.g. constant_velocity_continuous(q, axes=2, sigma_r2=...))
    times    (T,) seconds, strictly increasing, >= t0
    z        (T, m) measurements; NaN components skipped, a NaN row only predicts
    x0, P0   prior x(t0), P(t0); t0 defaults to times[0] (first step then has dt = 0)
    R        None (model.R), or (T, m, m) per-measurement noise covariances (e.g. from GPS accuracy)
    gate_probability  chi-square probability of the NIS gate; None disables gating
    reset_P0 covariance used when re-initialising at a measurement (default P0)
    """
    if not isinstance(model, ContinuousLinearModel):
        raise ParameterError(f"model: expected a ContinuousLinearModel, got {type(model).__name__}")
    t = as_array("times", times, ndim=1)
    z = as_sequence("z", z, model.m, allow_nan=True)
    if z.shape[0] != t.shape[0] or t.shape[0] == 0:
        raise ShapeError(f"z: expected {t.shape[0]} rows (one per time stamp, at least one), got shape {z.shape}")
    n, m, T = model.n, model.m, t.shape[0]
    x = as_vector("x0", x0, n)
    P = check_covariance("P0", P0, n)
    reset_P = P.copy() if reset_P0 is None else check_covariance("reset_P0", reset_P0, n)
    t0 = float(t[0]) if t0 is None else float(t0)
    dts = np.diff(np.r_[t0, t])
    if dts[0] < 0 or np.any(dts[1:] <= 0):
        k = int(np.flatnonzero(np.r_[dts[0] < 0, dts[1:] <= 0])[0])
        raise ParameterError(f"times: time stamps must increase strictly from t0; times[{k}] = {t[k]!r}")
    if R is None:
        Rs = np.broadcast_to(model.R, (T, m, m))
    else:
        Rs = as_array("R", R, shape=(T, m, m))
    check_int("max_rejections", max_rejections, minimum=2)
    gates = None if gate_probability is None else {d: nis_threshold(gate_probability, d) for d in range(1, m + 1)}
    H = model.H
    # the position rows of H pick the state entries a reset sets from z
    picks = [int(np.flatnonzero(H[i])[0]) for i in range(m)]
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    xp, Pp = np.empty((T, n)), np.empty((T, n, n))
    nis = np.full(T, np.nan)
    flag = np.zeros(T, dtype=np.int8)
    Fs, Qs = transitions(model, dts)
    loglik, rejected = 0.0, []  # indices of the consecutive rejected measurements
    vel = [p + 1 if p + 1 < n and model.Phi[p, p + 1] != 0 else None for p in picks]
    for k in range(T):
        F, Q = Fs[k], Qs[k]
        zk = z[k]
        ok = ~np.isnan(zk)
        if ok.any():
            x_pred, P_pred = F @ x, F @ P @ F.T + Q
            Hk, Rk = H[ok], Rs[k][np.ix_(ok, ok)]
            nu = zk[ok] - Hk @ x_pred
            S = Hk @ P_pred @ Hk.T + Rk
            nis[k] = float(nu @ scipy.linalg.solve(S, nu, assume_a="pos"))
            if gates is not None and nis[k] > gates[int(ok.sum())]:
                rejected = (rejected + [k])[-max_rejections:]
                fit = _line_fit(t, z, Rs, rejected, gates) if len(rejected) == max_rejections else None
                if fit is not None:  # the rejected fixes agree with each other: the terminal moved
                    flag[k], rejected = 3, []
                    x = x_pred.copy()
                    for i, p in enumerate(picks):
                        x[p] = fit[0][i]
                        if vel[i] is not None:
                            x[vel[i]] = fit[1][i]
                    xs[k], Ps[k], xp[k], Pp[k] = x, reset_P, x_pred, P_pred
                    P = reset_P.copy()
                    continue
                flag[k] = 1
                zk = np.full(m, np.nan)
            else:
                rejected = []
        else:
            flag[k] = 2
        x, P, xp[k], Pp[k], ll = kalman_step(F, H, Q, Rs[k], x, P, zk)
        xs[k], Ps[k] = x, P
        loglik += ll
    res = FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="KF-gated")
    return GatedResult(result=res, nis=nis, flag=flag, F=Fs, Q=Qs)


def _line_fit(t, z, Rs, idx, gates):
    """Least-squares straight line (position, velocity at the last time) through the measurements
    ``idx``, or None if some of them are not consistent with it (NIS of the residual over the gate)."""
    tt = t[idx] - t[idx[-1]]
    zz = z[idx]
    if np.isnan(zz).any():
        return None
    A = np.column_stack([np.ones_like(tt), tt])
    coef, *_ = np.linalg.lstsq(A, zz, rcond=None)  # (2, m): intercept, slope per component
    resid = zz - A @ coef
    for r, R in zip(resid, Rs[idx]):
        if float(r @ np.linalg.solve(R, r)) > gates[len(r)]:
            return None
    return coef[0], coef[1]


def rts_smoother_irregular(gated: GatedResult) -> FilterResult:
    """Rauch-Tung-Striebel smoother with a different (F, Q) per step (Anderson & Moore 1979, sec. 7.4):

        C(k)   = P(k/k) F(k+1)^T P(k+1/k)^{-1}
        x(k/T) = x(k/k) + C(k) [x(k+1/T) - x(k+1/k)]
        P(k/T) = P(k/k) + C(k) [P(k+1/T) - P(k+1/k)] C(k)^T

    Each stretch between filter resets is smoothed on its own (a reset breaks
    the chain of predictions).  Equal intervals give :func:`mptrack.linear.rts_smoother`.
    """
    r = gated.result
    xs, Ps = np.array(r.x), np.array(r.P)
    T = r.T
    for k in range(T - 2, -1, -1):
        if gated.flag[k + 1] == 3:
            continue
        P_pred = r.P_pred[k + 1]
        PFt = r.P[k] @ gated.F[k + 1].T
        try:
            C = scipy.linalg.solve(P_pred, PFt.T, assume_a="pos").T
        except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
            C = PFt @ np.linalg.pinv(P_pred)
        xs[k] = r.x[k] + C @ (xs[k + 1] - r.x_pred[k + 1])
        Pk = r.P[k] + C @ (Ps[k + 1] - P_pred) @ C.T
        Ps[k] = 0.5 * (Pk + Pk.T)
    return FilterResult(x=xs, P=Ps, method="RTS-irregular")
