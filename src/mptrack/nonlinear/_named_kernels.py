"""Compiled (numba) EKF and UKF for a linear motion (constant F, Q) observed by the named measurement
models (ranges, bearings, range_bearing, position and stacks of them, constant R).

:func:`mptrack.models.nonlinear_model` tags such a model with ``model.named = (F, codes, pos, stations)``
(codes: 0 range ||p - s||, 1 bearing atan2(p_y - s_y, p_x - s_x), 2 a state component; pos: the state
indices of the position, -1 padded).  :func:`ekf_filter`, :func:`ukf_filter` and
:func:`ekf_filter_batch` then validate once and run one compiled loop over the T steps (and the B
tracks) with the arithmetic of the generic path: Joseph-form EKF, unscented transform through f and h
with the circular mean of the angles, innovations wrapped into [-π, π), NaN components skipped, the
same log-likelihood: the compiled Kalman update of :mod:`mptrack._core.kalman`, which the generic
path also calls (through :mod:`mptrack.nonlinear._step_kernels`).  The tests pin the two paths to
1e-10 on identical inputs.

A kernel reports a problem (a non-positive-definite innovation covariance or square root, a
non-finite estimate) by a status code instead of raising; the caller then reruns the generic path,
which raises the specific error (or, for the UKF, takes the eigenvalue square root of a
semi-definite P).  Kernels are serial, for the reason given in :mod:`mptrack.continuous._kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.kalman import (
    DIVERGED,
    NOT_PD,
    OK,
    finite,
    observed,
    predict,
    record_update,
    store,
    unscented_update,
    update,
    workspace,
)
from ._step_kernels import _sigma, unscented_moments

__all__ = ["ekf_named", "ekf_named_batch", "ukf_named", "OK", "NOT_PD", "DIVERGED"]

_TINY = float(np.finfo(float).tiny)   # the models' range floor (mptrack.models._nonlinear)


@njit(cache=True, nogil=True)
def _range(x, pos, st, i):
    """||x[pos[i]] - st[i]|| over the valid (>= 0) position indices of component i."""
    acc = 0.0
    for j in range(3):
        if pos[i, j] >= 0:
            d = x[pos[i, j]] - st[i, j]
            acc += d * d
    return np.sqrt(acc)


@njit(cache=True, nogil=True)
def _h(x, codes, pos, st, out):
    """Measurement of one state x (n,) into out (m,)."""
    for i in range(codes.shape[0]):
        c = codes[i]
        if c == 2:
            out[i] = x[pos[i, 0]]
        elif c == 1:
            out[i] = np.arctan2(x[pos[i, 1]] - st[i, 1], x[pos[i, 0]] - st[i, 0])
        else:
            out[i] = _range(x, pos, st, i)


@njit(cache=True, nogil=True)
def _jac_h(x, codes, pos, st, H):
    """Analytic Jacobian (m, n) of the measurement at x, as the NumPy constructors compute it."""
    H[:, :] = 0.0
    for i in range(codes.shape[0]):
        c = codes[i]
        if c == 2:
            H[i, pos[i, 0]] = 1.0
        elif c == 1:
            dx = x[pos[i, 0]] - st[i, 0]
            dy = x[pos[i, 1]] - st[i, 1]
            r2 = max(dx * dx + dy * dy, _TINY)
            H[i, pos[i, 0]] = -dy / r2
            H[i, pos[i, 1]] = dx / r2
        else:
            r = max(_range(x, pos, st, i), _TINY)
            for j in range(3):
                if pos[i, j] >= 0:
                    H[i, pos[i, j]] = (x[pos[i, j]] - st[i, j]) / r


@njit(cache=True, nogil=True)
def _ekf_track(F, Q, R, codes, pos, st, periods, z, x0, P0, first, xs, Ps, xp, Pp, nus, Ss, nis):
    """One EKF run writing into xs, Ps, xp, Pp, nus, Ss, nis (T, ...; nus, Ss, nis NaN-filled by the caller);
    returns (status, step, loglik).  All work arrays are allocated once per run; the step is loops over
    them."""
    T, m = z.shape
    n = x0.shape[0]
    x = x0.copy()
    P = P0.copy()
    hx = np.empty(m)
    Hf = np.empty((m, n))
    ws = workspace(n, m)
    loglik = 0.0
    for k in range(T):
        if not (first and k == 0):
            predict(F, Q, x, P, ws)
        store(x, P, xp, Pp, k)
        _h(x, codes, pos, st, hx)
        _jac_h(x, codes, pos, st, Hf)
        status, ll = update(x, P, Hf, hx, R, z, k, periods, True, ws)
        if status != OK:
            return status, k, loglik
        record_update(ws, z, k, nus, Ss, nis, k)
        loglik += ll
        if not finite(x, P):
            return DIVERGED, k, loglik
        store(x, P, xs, Ps, k)
    return OK, T, loglik


@njit(cache=True, nogil=True)
def ekf_named(F, Q, R, codes, pos, st, periods, z, x0, P0, first, nus, Ss, nis):
    """One EKF run: (status, step, xs, Ps, xp, Pp, loglik); the innovations into nus, Ss, nis (NaN-filled)."""
    T = z.shape[0]
    n = x0.shape[0]
    xs, xp = np.empty((T, n)), np.empty((T, n))
    Ps, Pp = np.empty((T, n, n)), np.empty((T, n, n))
    status, step, loglik = _ekf_track(F, Q, R, codes, pos, st, periods, z, x0, P0, first, xs, Ps, xp, Pp, nus,
                                      Ss, nis)
    return status, step, xs, Ps, xp, Pp, loglik


@njit(cache=True, nogil=True)
def ekf_named_batch(F, Q, R, codes, pos, st, periods, z, x0, P0, xs, Ps, xp, Pp, nus, Ss, nis, loglik):
    """B tracks z (B, T, m), x0 (B, n), P0 (B, n, n) into the (B, T, ...) outputs; returns
    (status, track, step) of the first failure or (OK, B, T)."""
    B, T = z.shape[0], z.shape[1]
    for b in range(B):
        status, step, ll = _ekf_track(F, Q, R, codes, pos, st, periods, z[b], x0[b], P0[b], False,
                                      xs[b], Ps[b], xp[b], Pp[b], nus[b], Ss[b], nis[b])
        if status != OK:
            return status, b, step
        loglik[b] = ll
    return OK, B, T


@njit(cache=True, nogil=True)
def ukf_named(F, Q, R, codes, pos, st, periods, z, x0, P0, first, c, Wm, Wc, nus, Ss, nis):
    """The discrete UKF (scaled points, weights Wm, Wc, c = n + λ); returns
    (status, step, xs, Ps, xp, Pp, loglik); the innovations into nus, Ss, nis (NaN-filled)."""
    T, m = z.shape
    n = x0.shape[0]
    N = 2 * n + 1
    xs, xp = np.empty((T, n)), np.empty((T, n))
    Ps, Pp = np.empty((T, n, n)), np.empty((T, n, n))
    x = x0.copy()
    P = P0.copy()
    X = np.empty((N, n))
    Zf = np.empty((N, m))
    idx = np.empty(m, np.int64)
    loglik = 0.0
    for k in range(T):
        if not (first and k == 0):
            if not _sigma(x, P, c, X):
                return NOT_PD, k, xs, Ps, xp, Pp, loglik
            x, P = unscented_moments(X @ F.T, Wm, Wc, Q)
        store(x, P, xp, Pp, k)
        if observed(z, k, idx) > 0:
            if not _sigma(x, P, c, X):
                return NOT_PD, k, xs, Ps, xp, Pp, loglik
            for j in range(N):
                _h(X[j], codes, pos, st, Zf[j])
            status, x, P, ll = unscented_update(x, P, X, Zf, Wm, Wc, R, z, k, periods, nus, Ss, nis, k)
            if status != OK:
                return status, k, xs, Ps, xp, Pp, loglik
            loglik += ll
        if not finite(x, P):
            return DIVERGED, k, xs, Ps, xp, Pp, loglik
        store(x, P, xs, Ps, k)
    return OK, T, xs, Ps, xp, Pp, loglik
