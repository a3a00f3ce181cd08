"""Compiled (numba) time loops of the KF, LF and steady-state filters.

The equations are those of the readable single-step functions
:func:`kalman_step` and :func:`lainiotis_step` (the tests check that both give
the same numbers); the KF loop runs the one compiled predict/update of
:mod:`mptrack._core.kalman`; compiling the loop removes the per-call overhead of NumPy on
small matrices, which otherwise dominates (tens of microseconds per step).
Kernels are compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.kalman import OK, linear_update, predict, record_update, store, workspace

__all__ = ["kf_loop", "lf_loop", "ss_loop"]

@njit(cache=True)
def kf_loop(F, H, Q, R, z, x0, P0, joseph, xs, Ps, xps, Pps, nus, Ss, nis):  # pragma: no cover - compiled
    """KF over all steps; NaN components of z are skipped. Returns the log-likelihood.

    Predict and update are those of :mod:`mptrack._core.kalman` (standard form, or Joseph form when
    ``joseph``).  Writes the innovation, its covariance S and the NIS of the components used into nus
    (T, m), Ss (T, m, m) and nis (T,), which the caller fills with NaN (left there for missing
    components).  An innovation covariance without a Cholesky factor makes the rest of the run NaN
    (reported by the caller's finiteness check)."""
    T, m = z.shape
    n = F.shape[0]
    x = x0.copy()
    P = P0.copy()
    ws = workspace(n, m)
    hx = np.empty(m)
    periods = np.zeros(m)
    loglik = 0.0
    for k in range(T):
        predict(F, Q, x, P, ws)
        store(x, P, xps, Pps, k)
        status, ll = linear_update(x, P, H, R, z, k, periods, joseph, ws, hx)
        if status != OK:
            x[:] = np.nan
            P[:, :] = np.nan
            ll = np.nan
        else:
            record_update(ws, z, k, nus, Ss, nis, k)
        loglik += ll
        store(x, P, xs, Ps, k)
    return loglik


@njit(cache=True)
def lf_loop(F, Q, Kn, Km, Pn, Fn, On, z, x0, P0, xs, Ps):  # pragma: no cover - compiled
    """LF (Assimakis & Adam 2014, eqs. 5-6) over all steps; a row with NaN only predicts."""
    T, m = z.shape
    n = F.shape[0]
    x = x0.copy()
    P = P0.copy()
    Ft = np.ascontiguousarray(F.T)
    Fnt = np.ascontiguousarray(Fn.T)
    eye = np.eye(n)
    rhs = np.empty((n, n + 1))
    for k in range(T):
        zk = z[k]
        if np.isnan(zk).any():
            x = F @ x
            P = F @ P @ Ft + Q
        else:
            rhs[:, 0] = P @ (Km @ zk) + x
            rhs[:, 1:] = P
            sol = Fn @ np.linalg.solve(eye + P @ On, rhs)
            x = Kn @ zk + sol[:, 0]
            P = Pn + np.ascontiguousarray(sol[:, 1:]) @ Fnt
        P = 0.5 * (P + P.T)
        xs[k] = x
        Ps[k] = P


@njit(cache=True)
def ss_loop(A, B, F, z, x0, xs):  # pragma: no cover - compiled
    """x(k) = A x(k-1) + B z(k); a row with NaN predicts x(k) = F x(k-1)."""
    T, m = z.shape
    n = A.shape[0]
    x = x0.copy()
    for k in range(T):
        zk = z[k]
        missing = False
        for i in range(m):
            if np.isnan(zk[i]):
                missing = True
        xn = np.empty(n)
        for i in range(n):
            acc = 0.0
            if missing:
                for j in range(n):
                    acc += F[i, j] * x[j]
            else:
                for j in range(n):
                    acc += A[i, j] * x[j]
                for j in range(m):
                    acc += B[i, j] * zk[j]
            xn[i] = acc
        x = xn
        xs[k] = x
