"""Kalman filtering of irregularly sampled measurements: the continuous model is
discretised exactly (Van Loan) for every interval between time stamps."""

from __future__ import annotations

import numpy as np

from .._validation import as_array, as_sequence, as_vector, check_covariance
from ..errors import ParameterError, ShapeError
from ..models import ContinuousLinearModel
from ..models._continuous import _van_loan
from ._kalman import kalman_step
from ._result import FilterResult

__all__ = ["kalman_filter_irregular", "sampling_intervals"]


def sampling_intervals(times, t0: float = 0.0) -> np.ndarray:
    """The intervals dt(k) = t(k) - t(k-1) > 0 (seconds) of time stamps t(1..T) after t(0) = t0.

    Raises ParameterError naming the first time stamp that does not increase.
    """
    t = as_array("times", times, ndim=1)
    if t.shape[0] == 0:
        raise ShapeError("times: expected at least one time stamp, got shape (0,)")
    t0 = float(as_array("t0", t0, ndim=0))
    dts = np.diff(np.concatenate(([t0], t)))
    bad = np.flatnonzero(dts <= 0)
    if bad.size:
        k = int(bad[0])
        before = t0 if k == 0 else float(t[k - 1])
        where = "t0" if k == 0 else f"times[{k - 1}]"
        raise ParameterError(f"times: time stamps must increase strictly; times[{k}] = {float(t[k])!r} "
                             f"is not after {where} = {before!r}")
    return dts


def kalman_filter_irregular(model: ContinuousLinearModel, times, z, x0=None, P0=None, *,
                            t0: float = 0.0, joseph: bool = False) -> FilterResult:
    """Kalman filter for measurements at arbitrary increasing time stamps.

    model   a ContinuousLinearModel (dx = Phi x dt + L dbeta, z = H x + v)
    times   (T,) time stamps t(1..T) of z(1..T), seconds, strictly increasing and > t0
    z       (T, m) measurements; NaN components are skipped, a NaN row only predicts
    x0, P0  the prior x(0/0), P(0/0) at time t0 (default zeros)

    Each step uses F = e^{Phi dt(k)}, Q = int_0^dt(k) e^{Phi s} L Qc L^T e^{Phi^T s} ds
    (seed 001 sec. 2, Van Loan's method), cached per distinct interval.  With
    equal intervals dt this is :func:`kalman_filter` on ``model.discretize(dt)``.
    """
    if not isinstance(model, ContinuousLinearModel):
        raise ParameterError(f"model: expected a ContinuousLinearModel, got {type(model).__name__}")
    dts = sampling_intervals(times, t0)
    z = as_sequence("z", z, model.m, allow_nan=True)
    if z.shape[0] != dts.shape[0]:
        raise ShapeError(f"z: expected {dts.shape[0]} rows (one per time stamp), got shape {z.shape}")
    x = np.zeros(model.n) if x0 is None else as_vector("x0", x0, model.n)
    P = np.zeros((model.n, model.n)) if P0 is None else check_covariance("P0", P0, model.n)
    T, n = z.shape[0], model.n
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    xp, Pp = np.empty((T, n)), np.empty((T, n, n))
    LQL = model.L @ model.Qc @ model.L.T
    cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    loglik = 0.0
    for k in range(T):
        dt = float(dts[k])
        if dt not in cache:
            cache[dt] = _van_loan(model.Phi, LQL, dt)
        F, Q = cache[dt]
        x, P, xp[k], Pp[k], ll = kalman_step(F, model.H, Q, model.R, x, P, z[k], joseph)
        xs[k], Ps[k] = x, P
        loglik += ll
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="KF-irregular")
