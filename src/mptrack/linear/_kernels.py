"""Compiled (numba) time loops of the KF, LF and steady-state filters.

The equations are those of the readable single-step functions
:func:`kalman_step` and :func:`lainiotis_step` (the tests check that both give
the same numbers); compiling the loop removes the per-call overhead of NumPy on
small matrices, which otherwise dominates (tens of microseconds per step).
Kernels are compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import _jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

__all__ = ["kf_loop", "lf_loop", "ss_loop"]

_LOG2PI = np.log(2.0 * np.pi)


@njit(cache=True)
def kf_loop(F, H, Q, R, z, x0, P0, joseph, xs, Ps, xps, Pps):  # pragma: no cover - compiled
    """KF over all steps; NaN components of z are skipped. Returns the log-likelihood."""
    T, m = z.shape
    n = F.shape[0]
    x = x0.copy()
    P = P0.copy()
    Ft = np.ascontiguousarray(F.T)
    eye = np.eye(n)
    loglik = 0.0
    for k in range(T):
        xp = F @ x
        Pp = F @ P @ Ft + Q
        xps[k] = xp
        Pps[k] = Pp
        zk = z[k]
        n_ok = 0
        for i in range(m):
            if not np.isnan(zk[i]):
                n_ok += 1
        if n_ok == 0:
            x = xp
            P = Pp
        else:
            if n_ok == m:
                Hk, Rk, zv = H, R, zk
            else:
                idx = np.empty(n_ok, dtype=np.int64)
                j = 0
                for i in range(m):
                    if not np.isnan(zk[i]):
                        idx[j] = i
                        j += 1
                Hk = np.ascontiguousarray(H[idx])
                Rk = np.empty((n_ok, n_ok))
                for a in range(n_ok):
                    for b in range(n_ok):
                        Rk[a, b] = R[idx[a], idx[b]]
                zv = zk[idx]
            PHt = Pp @ np.ascontiguousarray(Hk.T)
            S = Hk @ PHt + Rk
            Si = np.linalg.inv(S)
            K = PHt @ Si
            innov = zv - Hk @ xp
            x = xp + K @ innov
            if joseph:
                IKH = eye - K @ Hk
                P = IKH @ Pp @ np.ascontiguousarray(IKH.T) + K @ Rk @ np.ascontiguousarray(K.T)
            else:
                P = Pp - K @ np.ascontiguousarray(PHt.T)
            P = 0.5 * (P + P.T)
            loglik -= 0.5 * (innov @ (Si @ innov) + np.log(np.linalg.det(S)) + n_ok * _LOG2PI)
        xs[k] = x
        Ps[k] = P
    return loglik


@njit(cache=True)
def lf_loop(F, Q, Kn, Km, Pn, Fn, On, z, x0, P0, xs, Ps):  # pragma: no cover - compiled
    """LF (seed 000 eqs. 5-6) over all steps; a row with NaN only predicts."""
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
