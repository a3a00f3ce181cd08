"""Kalman filtering of irregularly sampled measurements: the continuous model is
discretised exactly (Van Loan) for every interval between time stamps."""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result, renamed
from .._core.rts import rts_backward_linear
from .._core.validation import as_array, as_sequence, as_vector, check_covariance, check_record
from .._core.van_loan import intervals_unchecked
from ..errors import ParameterError, ShapeError
from ..models import ContinuousLinearModel, require_model
from ..result import FilterResult, innovation_arrays
from ._kernels import kf_loop

__all__ = ["kalman_filter_irregular", "rts_smoother_irregular", "sampling_intervals"]


def sampling_intervals(times, t0: float = 0.0) -> np.ndarray:
    """The intervals dt(k) = t(k) - t(k-1) of time stamps after t(0) = t0.

    Parameters
    ----------
    times : array_like, shape (T,)
        Time stamps (s).
    t0 : float, optional
        The time before the first stamp (s).

    Returns
    -------
    ndarray, shape (T,)
        The intervals, all > 0.

    Raises
    ------
    ParameterError
        A time stamp that does not increase (the message names the first).
    """
    t = as_array("times", times, ndim=1)
    if t.shape[0] == 0:
        raise ShapeError("times: expected at least one time stamp, got shape (0,)")
    t0 = float(as_array("t0", t0, ndim=0))
    stamps = np.concatenate(([t0], t))
    bad = np.flatnonzero(~(stamps[1:] > stamps[:-1]))
    if bad.size:
        k = int(bad[0])
        before = t0 if k == 0 else float(t[k - 1])
        where = "t0" if k == 0 else f"times[{k - 1}]"
        raise ParameterError(f"times: time stamps must increase strictly; times[{k}] = {float(t[k])!r} "
                             f"is not after {where} = {before!r}")
    with np.errstate(over="ignore"):
        dts = np.diff(stamps)
    if not np.all(np.isfinite(dts)):
        k = int(np.flatnonzero(~np.isfinite(dts))[0])
        raise ParameterError(f"times: the interval before times[{k}] overflows float64")
    return dts


@finite_result("the irregular-time Kalman filter")
def kalman_filter_irregular(model: ContinuousLinearModel, times, z, x0=None, P0=None, *,
                            t0: float = 0.0, joseph: bool = False) -> FilterResult:
    """Kalman filter for measurements at arbitrary increasing time stamps.

    Each step uses F = e^(Phi dt(k)) and its exact Q (Assimakis et al. 2016, sec. 2; Van Loan's method,
    :func:`mptrack.models.discretize_intervals`); runs of equal intervals go through the compiled loop of
    :func:`kalman_filter` in one call, so equal intervals give :func:`kalman_filter` exactly.

    Parameters
    ----------
    model : ContinuousLinearModel
        dx = Phi x dt + L dbeta, z = H x + v.
    times : array_like, shape (T,)
        Time stamps t(1..T) of the measurements (s), strictly increasing and > t0.
    z : array_like, shape (T, m)
        Measurements z(1..T); NaN components are missing (a NaN row only predicts).
    x0 : array_like, shape (n,), optional
        The prior x(0/0) at time t0 (default zeros).
    P0 : array_like, shape (n, n)
        The prior covariance at t0, required.
    t0 : float, optional
        The prior's time (s).
    joseph : bool, optional
        Joseph form of the covariance update.

    Returns
    -------
    FilterResult

    Raises
    ------
    ParameterError
        A time stamp that does not increase (the message names its index).

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    .. [2] C. F. Van Loan, "Computing integrals involving the matrix exponential", IEEE Transactions on
           Automatic Control, vol. 23, no. 3, pp. 395–404, 1978. doi:10.1109/TAC.1978.1101743
    """
    require_model(model, kind=ContinuousLinearModel)
    dts = sampling_intervals(times, t0)
    z = as_sequence("z", z, model.m, allow_nan=True)
    if z.shape[0] != dts.shape[0]:
        raise ShapeError(f"z: expected {dts.shape[0]} rows (one per time stamp), got shape {z.shape}")
    x = np.zeros(model.n) if x0 is None else as_vector("x0", x0, model.n)
    P = np.zeros((model.n, model.n)) if P0 is None else check_covariance("P0", P0, model.n)
    z = np.ascontiguousarray(z)
    T, n = z.shape[0], model.n
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    xp, Pp = np.empty((T, n)), np.empty((T, n, n))
    nu, S, nis = innovation_arrays((T,), model.m)
    with renamed(dt="times"):
        Fs, Qs = intervals_unchecked(model, dts)
    loglik = 0.0
    # runs of equal intervals share (F, Q) and go through the compiled KF loop in one call
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(dts)) + 1, [T]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        loglik += kf_loop(Fs[a], model.H, Qs[a], model.R, z[a:b], x, P, bool(joseph),
                          xs[a:b], Ps[a:b], xp[a:b], Pp[a:b], nu[a:b], S[a:b], nis[a:b])
        x, P = xs[b - 1], Ps[b - 1]
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="KF-irregular",
                        innovation=nu, S=S, nis=nis)


@finite_result("the irregular-time RTS smoother")
def rts_smoother_irregular(model: ContinuousLinearModel, times, result: FilterResult, *,
                           t0: float = 0.0) -> FilterResult:
    """Fixed-interval RTS smoother for a filter run at irregular time stamps: the backward pass of
    :func:`rts_smoother` with F, Q rediscretised for every interval.

    Parameters
    ----------
    model : ContinuousLinearModel
        The model the filter ran with.
    times : array_like, shape (T,)
        The time stamps the filter ran with (s).
    result : FilterResult
        The filter's result (e.g. :func:`kalman_filter_irregular`).
    t0 : float, optional
        The prior's time the filter ran with (s).

    Returns
    -------
    FilterResult

    References
    ----------
    .. [1] H. E. Rauch, F. Tung and C. T. Striebel, "Maximum likelihood estimates of linear dynamic systems",
           AIAA Journal, vol. 3, no. 8, pp. 1445–1450, 1965. doi:10.2514/3.3166
    """
    require_model(model, kind=ContinuousLinearModel)
    if not isinstance(result, FilterResult):
        raise ParameterError(f"result: expected a FilterResult, got {type(result).__name__}")
    check_record("result", result)
    dts = sampling_intervals(times, t0)
    if result.T != dts.shape[0] or result.n != model.n:
        raise ShapeError(f"result: expected {dts.shape[0]} steps of an n = {model.n} state "
                         f"(one per time stamp), got x of shape {result.x.shape}")
    with renamed(dt="times"):
        Fs, Qs = intervals_unchecked(model, dts[1:])
    return rts_backward_linear(result, Fs, Qs)
