"""Compiled (numba) EKF and UKF for a linear motion (constant F, Q) observed by the named measurement
models (ranges, bearings, range_bearing, position and stacks of them, constant R).

:func:`mptrack.models.nonlinear_model` tags such a model with ``model.named = (F, codes, pos, stations)``
(codes: 0 range ||p - s||, 1 bearing atan2(p_y - s_y, p_x - s_x), 2 a state component; pos: the state
indices of the position, -1 padded).  :func:`ekf_filter`, :func:`ukf_filter` and
:func:`ekf_filter_batch` then validate once and run one compiled loop over the T steps (and the B
tracks) with the arithmetic of the NumPy path: Joseph-form EKF, unscented transform through f and h
with the circular mean of the angles, innovations wrapped into [-π, π), NaN components skipped, the
same log-likelihood.  The tests pin the two paths to 1e-10 on identical inputs.

A kernel reports a problem (a non-positive-definite innovation covariance or square root, a
non-finite estimate) by a status code instead of raising; the caller then reruns the NumPy path,
which raises the specific error (or, for the UKF, takes the eigenvalue square root of a
semi-definite P).  Kernels are serial, for the reason given in :mod:`mptrack.nonlinear._kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import _jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

__all__ = ["ekf_named", "ekf_named_batch", "ukf_named"]

_LOG2PI = float(np.log(2.0 * np.pi))
_TINY = 1e-12
_TWO_PI = 2.0 * np.pi

OK, NOT_PD, DIVERGED = 0, 1, 2


@njit(cache=True, nogil=True)
def _wrap(v):
    return (v + np.pi) % _TWO_PI - np.pi


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
def _cholesky(S, L, q):
    """Lower Cholesky factor of S[:q, :q] into L[:q, :q]; False when S is not positive definite."""
    for i in range(q):
        for j in range(q):
            L[i, j] = 0.0
    for j in range(q):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, q):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


@njit(cache=True, nogil=True)
def _chol_solve(L, b, out, q):
    """out[:q] = S^-1 b[:q] with S = L L^T (L[:q, :q])."""
    for i in range(q):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * out[k]
        out[i] = s / L[i, i]
    for i in range(q - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, q):
            s -= L[k, i] * out[k]
        out[i] = s / L[i, i]


@njit(cache=True, nogil=True)
def _gain_loglik(L, nu, PHt, K, w, n, q):
    """K[:n, :q] = PHt S^-1 (rows solved with the Cholesky factor L of S, all [:q]) and log N(nu; 0, S)."""
    for a in range(n):
        _chol_solve(L, PHt[a], K[a], q)
    quad = 0.0
    logdet = 0.0
    for i in range(q):
        s = nu[i]
        for k in range(i):
            s -= L[i, k] * w[k]
        w[i] = s / L[i, i]
        quad += w[i] * w[i]
        logdet += np.log(L[i, i])
    return -0.5 * (quad + 2.0 * logdet + q * _LOG2PI)


@njit(cache=True, nogil=True)
def _finite(x, P):
    acc = 0.0
    for a in range(x.shape[0]):
        acc += x[a]
        for b in range(x.shape[0]):
            acc += P[a, b]
    return np.isfinite(acc)


@njit(cache=True, nogil=True)
def _symmetrise(P):
    n = P.shape[0]
    for a in range(n):
        for b in range(a + 1, n):
            v = 0.5 * (P[a, b] + P[b, a])
            P[a, b] = v
            P[b, a] = v


@njit(cache=True, nogil=True)
def _mul(A, B, out, ni, nk, nj):
    """out[:ni, :nj] = A[:ni, :nk] B[:nk, :nj] (explicit loops: no temporaries, views or BLAS calls for
    these small matrices)."""
    for i in range(ni):
        for j in range(nj):
            acc = 0.0
            for k in range(nk):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@njit(cache=True, nogil=True)
def _sym_bt(A, B, out, n, nk):
    """out[:n, :n] = A[:n, :nk] B[:n, :nk]^T for a product known to be symmetric: the upper triangle,
    mirrored (the NumPy path's 0.5 (P + P^T) up to rounding)."""
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for k in range(nk):
                acc += A[i, k] * B[j, k]
            out[i, j] = acc
            out[j, i] = acc


@njit(cache=True, nogil=True)
def _observed(z, k, idx):
    """The indices of the non-NaN components of z[k] into idx; returns their count."""
    q = 0
    for i in range(z.shape[1]):
        if not np.isnan(z[k, i]):
            idx[q] = i
            q += 1
    return q


@njit(cache=True, nogil=True)
def _store(x, P, xs, Ps, k):
    """xs[k], Ps[k] = x, P."""
    n = x.shape[0]
    for a in range(n):
        xs[k, a] = x[a]
        for b in range(n):
            Ps[k, a, b] = P[a, b]


@njit(cache=True, nogil=True)
def _ekf_track(F, Q, R, codes, pos, st, angles, z, x0, P0, first, xs, Ps, xp, Pp):
    """One EKF run writing into xs, Ps, xp, Pp (T, ...); returns (status, step, loglik).  All work arrays
    are allocated once per run; the step is loops over them."""
    T, m = z.shape
    n = x0.shape[0]
    x = x0.copy()
    P = P0.copy()
    xn = np.empty(n)
    A = np.empty((n, n))
    IKH = np.empty((n, n))
    hx = np.empty(m)
    Hf = np.empty((m, n))
    idx = np.empty(m, np.int64)
    H = np.empty((m, n))
    Rq = np.empty((m, m))
    nu = np.empty(m)
    HP = np.empty((m, n))
    PHt = np.empty((n, m))
    S = np.empty((m, m))
    L = np.empty((m, m))
    K = np.empty((n, m))
    KR = np.empty((n, m))
    w = np.empty(m)
    loglik = 0.0
    for k in range(T):
        if not (first and k == 0):
            for a in range(n):
                acc = 0.0
                for b in range(n):
                    acc += F[a, b] * x[b]
                xn[a] = acc
            _mul(F, P, A, n, n, n)
            _sym_bt(A, F, P, n, n)
            for a in range(n):
                x[a] = xn[a]
                for b in range(n):
                    P[a, b] += Q[a, b]
        _store(x, P, xp, Pp, k)
        q = _observed(z, k, idx)
        if q > 0:
            _h(x, codes, pos, st, hx)
            _jac_h(x, codes, pos, st, Hf)
            for a in range(q):
                i = idx[a]
                for b in range(n):
                    H[a, b] = Hf[i, b]
                v = z[k, i] - hx[i]
                nu[a] = _wrap(v) if angles[i] else v
                for b in range(q):
                    Rq[a, b] = R[i, idx[b]]
            _mul(H, P, HP, q, n, n)
            _sym_bt(HP, H, S, q, n)
            for a in range(q):
                for b in range(q):
                    S[a, b] += Rq[a, b]
            for a in range(n):
                for b in range(q):
                    PHt[a, b] = HP[b, a]
            if not _cholesky(S, L, q):
                return NOT_PD, k, loglik
            ll = _gain_loglik(L, nu, PHt, K, w, n, q)
            for a in range(n):
                acc = 0.0
                for b in range(q):
                    acc += K[a, b] * nu[b]
                x[a] += acc
            _mul(K, H, IKH, n, q, n)
            for a in range(n):
                for b in range(n):
                    IKH[a, b] = (1.0 if a == b else 0.0) - IKH[a, b]
            _mul(IKH, P, A, n, n, n)
            _sym_bt(A, IKH, P, n, n)
            _mul(K, Rq, KR, n, q, q)
            for a in range(n):
                for b in range(a, n):
                    acc = 0.0
                    for c in range(q):
                        acc += KR[a, c] * K[b, c]
                    P[a, b] += acc
                    if b != a:
                        P[b, a] = P[a, b]
            loglik += ll
        if not _finite(x, P):
            return DIVERGED, k, loglik
        _store(x, P, xs, Ps, k)
    return OK, T, loglik


@njit(cache=True, nogil=True)
def ekf_named(F, Q, R, codes, pos, st, angles, z, x0, P0, first):
    T = z.shape[0]
    n = x0.shape[0]
    xs, xp = np.empty((T, n)), np.empty((T, n))
    Ps, Pp = np.empty((T, n, n)), np.empty((T, n, n))
    status, step, loglik = _ekf_track(F, Q, R, codes, pos, st, angles, z, x0, P0, first, xs, Ps, xp, Pp)
    return status, step, xs, Ps, xp, Pp, loglik


@njit(cache=True, nogil=True)
def ekf_named_batch(F, Q, R, codes, pos, st, angles, z, x0, P0, xs, Ps, xp, Pp, loglik):
    """B tracks z (B, T, m), x0 (B, n), P0 (B, n, n) into the (B, T, ...) outputs; returns
    (status, track, step) of the first failure or (OK, B, T)."""
    B, T = z.shape[0], z.shape[1]
    for b in range(B):
        status, step, ll = _ekf_track(F, Q, R, codes, pos, st, angles, z[b], x0[b], P0[b], False,
                                      xs[b], Ps[b], xp[b], Pp[b])
        if status != OK:
            return status, b, step
        loglik[b] = ll
    return OK, B, T


@njit(cache=True, nogil=True)
def _sigma(x, P, c, X):
    """The 2n+1 sigma points of N(x, P) into X; False when c P has no Cholesky factor."""
    n = x.shape[0]
    L = np.empty((n, n))
    if not _cholesky(c * P, L, n):
        return False
    for a in range(n):
        X[0, a] = x[a]
    for i in range(n):
        for a in range(n):
            X[1 + i, a] = x[a] + L[a, i]
            X[1 + n + i, a] = x[a] - L[a, i]
    return True


@njit(cache=True, nogil=True)
def ukf_named(F, Q, R, codes, pos, st, angles, z, x0, P0, first, c, Wm, Wc):
    """The discrete UKF (scaled points, weights Wm, Wc, c = n + λ); returns
    (status, step, xs, Ps, xp, Pp, loglik)."""
    T, m = z.shape
    n = x0.shape[0]
    N = 2 * n + 1
    xs, xp = np.empty((T, n)), np.empty((T, n))
    Ps, Pp = np.empty((T, n, n)), np.empty((T, n, n))
    x = x0.copy()
    P = P0.copy()
    X = np.empty((N, n))
    Zf = np.empty((N, m))
    zbar = np.empty(m)
    idx = np.empty(m, np.int64)
    loglik = 0.0
    for k in range(T):
        if not (first and k == 0):
            if not _sigma(x, P, c, X):
                return NOT_PD, k, xs, Ps, xp, Pp, loglik
            Y = X @ F.T
            x = Wm @ Y
            dY = Y - x
            P = (Wc.reshape(N, 1) * dY).T @ dY + Q
            _symmetrise(P)
        _store(x, P, xp, Pp, k)
        q = _observed(z, k, idx)
        if q > 0:
            if not _sigma(x, P, c, X):
                return NOT_PD, k, xs, Ps, xp, Pp, loglik
            for j in range(N):
                _h(X[j], codes, pos, st, Zf[j])
            for i in range(m):
                if angles[i]:
                    sn = 0.0
                    cs = 0.0
                    for j in range(N):
                        sn += Wm[j] * np.sin(Zf[j, i])
                        cs += Wm[j] * np.cos(Zf[j, i])
                    zbar[i] = np.arctan2(sn, cs)
                else:
                    acc = 0.0
                    for j in range(N):
                        acc += Wm[j] * Zf[j, i]
                    zbar[i] = acc
            dZ = np.empty((N, q))
            nu = np.empty(q)
            Rq = np.empty((q, q))
            for a in range(q):
                i = idx[a]
                for j in range(N):
                    v = Zf[j, i] - zbar[i]
                    dZ[j, a] = _wrap(v) if angles[i] else v
                v = z[k, i] - zbar[i]
                nu[a] = _wrap(v) if angles[i] else v
                for b in range(q):
                    Rq[a, b] = R[i, idx[b]]
            WdZ = Wc.reshape(N, 1) * dZ
            S = WdZ.T @ dZ + Rq
            C = (Wc.reshape(N, 1) * (X - x)).T @ dZ
            L = np.empty((q, q))
            if not _cholesky(S, L, q):
                return NOT_PD, k, xs, Ps, xp, Pp, loglik
            K = np.empty((n, q))
            w = np.empty(q)
            ll = _gain_loglik(L, nu, C, K, w, n, q)
            x = x + K @ nu
            P = P - K @ S @ K.T
            _symmetrise(P)
            loglik += ll
        if not _finite(x, P):
            return DIVERGED, k, xs, Ps, xp, Pp, loglik
        _store(x, P, xs, Ps, k)
    return OK, T, xs, Ps, xp, Pp, loglik
