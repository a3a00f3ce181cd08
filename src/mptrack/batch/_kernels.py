"""Compiled (numba) kernels of the batch engine.

Layout: measurements ``z`` (B, T, m_total) and states ``out`` (B, T, n_total),
C-contiguous, float64 or float32.  The parallel loop runs over *tracks*
(``prange``); each track is one sequential recursion over time that reads one
contiguous stream of ``z`` and writes one contiguous stream of ``out``, so
each thread streams through memory front to back (hardware prefetch friendly)
and never shares a cache line with another thread except at track borders.

Axes as extra batch (model B run per axis, seed 000 eqs. 17-18): a track is
the pair (b, a) with ``a < axes``; it reads columns ``a*m .. a*m+m-1`` of
``z[b]`` and writes columns ``a*n .. a*n+n-1`` of ``out[b]``.  ``axes = 1`` is
the plain joint model.

The state is carried in float64 whatever the storage dtype; float32 only
halves the bytes streamed.  Steps ``t >= lengths[b]`` are written as NaN.
The model matrices are always float64, so each kernel compiles once per
storage dtype (two signatures in total), and ``cache=True`` keeps the
machine code between processes.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["ss_kernel", "ss_kernel_21", "kf_kernel", "kf_kernel_21", "fir_kernel", "matvec_kernel",
           "copy_kernel"]

_OPTS = dict(parallel=True, cache=True, nogil=True, boundscheck=False)


@nb.njit(**_OPTS)
def ss_kernel(z, out, A, Bm, F, x0, lengths, axes):
    """x(k/k) = A x(k-1/k-1) + B z(k) (seed 000 eq. 9); a row with NaN predicts, x = F x."""
    nb_, T = z.shape[0], z.shape[1]
    n = A.shape[0]
    m = Bm.shape[1]
    for i in nb.prange(nb_ * axes):
        b = i // axes
        zo = (i - b * axes) * m
        xo = (i - b * axes) * n
        x = np.empty(n)
        xn = np.empty(n)
        for r in range(n):
            x[r] = x0[b, xo + r]
        L = lengths[b]
        for t in range(L):
            miss = False
            for c in range(m):
                if np.isnan(z[b, t, zo + c]):
                    miss = True
            if miss:
                for r in range(n):
                    s = 0.0
                    for c in range(n):
                        s += F[r, c] * x[c]
                    xn[r] = s
            else:
                for r in range(n):
                    s = 0.0
                    for c in range(n):
                        s += A[r, c] * x[c]
                    u = 0.0
                    for c in range(m):
                        u += Bm[r, c] * z[b, t, zo + c]
                    xn[r] = s + u
            for r in range(n):
                x[r] = xn[r]
                out[b, t, xo + r] = xn[r]
        for t in range(L, T):
            for r in range(n):
                out[b, t, xo + r] = np.nan


@nb.njit(**_OPTS)
def ss_kernel_21(z, out, A, Bm, F, x0, lengths, axes):
    """:func:`ss_kernel` written out for n = 2, m = 1 (model B per axis): the state
    lives in registers, so the loop runs at memory speed."""
    nb_, T = z.shape[0], z.shape[1]
    a00, a01, a10, a11 = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    b0, b1 = Bm[0, 0], Bm[1, 0]
    f00, f01, f10, f11 = F[0, 0], F[0, 1], F[1, 0], F[1, 1]
    for i in nb.prange(nb_ * axes):
        b = i // axes
        a = i - b * axes
        o = 2 * a
        p = x0[b, o]
        v = x0[b, o + 1]
        L = lengths[b]
        for t in range(L):
            zz = z[b, t, a]
            if np.isnan(zz):
                p, v = f00 * p + f01 * v, f10 * p + f11 * v
            else:
                p, v = (a00 * p + a01 * v) + b0 * zz, (a10 * p + a11 * v) + b1 * zz
            out[b, t, o] = p
            out[b, t, o + 1] = v
        for t in range(L, T):
            out[b, t, o] = np.nan
            out[b, t, o + 1] = np.nan


@nb.njit(cache=True, nogil=True)
def _kf_full_update(F, H, Q, R, x, P, zrow, zo):
    """One Kalman step (seed 000 eq. 4) with this track's own covariance P (in place).

    NaN components of the measurement are skipped; a fully missing row only
    predicts.  The gain solves S K^T = (P H^T)^T by Cholesky (S is positive
    definite); written with explicit loops to keep compile time low.
    """
    n = F.shape[0]
    m = H.shape[0]
    xp = np.zeros(n)
    FP = np.zeros((n, n))
    Pp = np.empty((n, n))
    for r in range(n):
        for c in range(n):
            xp[r] += F[r, c] * x[c]
            for j in range(n):
                FP[r, c] += F[r, j] * P[j, c]
    for r in range(n):
        for c in range(n):
            s = 0.0
            for j in range(n):
                s += FP[r, j] * F[c, j]
            Pp[r, c] = s + Q[r, c]
    ok = np.empty(m, dtype=np.int64)
    k = 0
    for c in range(m):
        if not np.isnan(zrow[zo + c]):
            ok[k] = c
            k += 1
    if k == 0:
        for r in range(n):
            x[r] = xp[r]
            for c in range(n):
                P[r, c] = Pp[r, c]
        return
    PHt = np.zeros((n, k))          # P(k/k-1) H^T
    for r in range(n):
        for i in range(k):
            for j in range(n):
                PHt[r, i] += Pp[r, j] * H[ok[i], j]
    Lc = np.zeros((k, k))           # S = H P H^T + R = Lc Lc^T
    for i in range(k):
        for j in range(i + 1):
            s = R[ok[i], ok[j]]
            for c in range(n):
                s += H[ok[i], c] * PHt[c, j]
            for c in range(j):
                s -= Lc[i, c] * Lc[j, c]
            Lc[i, j] = np.sqrt(s) if i == j else s / Lc[j, j]
    innov = np.empty(k)
    for i in range(k):
        s = zrow[zo + ok[i]]
        for j in range(n):
            s -= H[ok[i], j] * xp[j]
        innov[i] = s
    G = np.empty((n, k))            # K = PHt S^{-1}: solve Lc Lc^T K^T = PHt^T row by row
    for r in range(n):
        for i in range(k):
            s = PHt[r, i]
            for c in range(i):
                s -= Lc[i, c] * G[r, c]
            G[r, i] = s / Lc[i, i]
        for i in range(k - 1, -1, -1):
            s = G[r, i]
            for c in range(i + 1, k):
                s -= Lc[c, i] * G[r, c]
            G[r, i] = s / Lc[i, i]
    for r in range(n):
        s = xp[r]
        for i in range(k):
            s += G[r, i] * innov[i]
        x[r] = s
    for r in range(n):
        for c in range(n):
            s = Pp[r, c]
            for i in range(k):
                s -= G[r, i] * PHt[c, i]
            P[r, c] = s
    for r in range(n):
        for c in range(r):
            avg = 0.5 * (P[r, c] + P[c, r])
            P[r, c] = avg
            P[c, r] = avg


@nb.njit(**_OPTS)
def kf_kernel(z, out, F, H, Q, R, K, Pf, P0, x0, lengths, axes):
    """Kalman filter with the shared gain sequence K[t] (seed 000 eq. 4).

    While a track's measurements are complete it uses the precomputed gains:
    x(k/k-1) = F x(k-1/k-1), x(k/k) = x(k/k-1) + K(k) [z(k) - H x(k/k-1)].
    At its first missing component it leaves the shared sequence: it takes
    P(k-1/k-1) = Pf[k-1] (or P0) and runs its own Riccati recursion from there.
    """
    nb_, T = z.shape[0], z.shape[1]
    n = F.shape[0]
    m = H.shape[0]
    for i in nb.prange(nb_ * axes):
        b = i // axes
        zo = (i - b * axes) * m
        xo = (i - b * axes) * n
        x = np.empty(n)
        xp = np.empty(n)
        innov = np.empty(m)
        P = np.empty((n, n))
        shared = True
        for r in range(n):
            x[r] = x0[b, xo + r]
        L = lengths[b]
        for t in range(L):
            if shared:
                miss = False
                for c in range(m):
                    if np.isnan(z[b, t, zo + c]):
                        miss = True
                if miss:
                    shared = False
                    for r in range(n):
                        for c in range(n):
                            P[r, c] = P0[r, c] if t == 0 else Pf[t - 1, r, c]
            if shared:
                for r in range(n):
                    s = 0.0
                    for c in range(n):
                        s += F[r, c] * x[c]
                    xp[r] = s
                for c in range(m):
                    s = 0.0
                    for j in range(n):
                        s += H[c, j] * xp[j]
                    innov[c] = z[b, t, zo + c] - s
                for r in range(n):
                    s = 0.0
                    for c in range(m):
                        s += K[t, r, c] * innov[c]
                    x[r] = xp[r] + s
            else:
                _kf_full_update(F, H, Q, R, x, P, z[b, t], zo)
            for r in range(n):
                out[b, t, xo + r] = x[r]
        for t in range(L, T):
            for r in range(n):
                out[b, t, xo + r] = np.nan


@nb.njit(**_OPTS)
def kf_kernel_21(z, out, F, H, Q, R, K, Pf, P0, x0, lengths, axes):
    """:func:`kf_kernel` written out for n = 2, m = 1 (model B per axis)."""
    nb_, T = z.shape[0], z.shape[1]
    f00, f01, f10, f11 = F[0, 0], F[0, 1], F[1, 0], F[1, 1]
    h0, h1 = H[0, 0], H[0, 1]
    for i in nb.prange(nb_ * axes):
        b = i // axes
        a = i - b * axes
        o = 2 * a
        p = x0[b, o]
        v = x0[b, o + 1]
        L = lengths[b]
        t0 = L
        for t in range(L):
            zz = z[b, t, a]
            if np.isnan(zz):
                t0 = t
                break
            pp = f00 * p + f01 * v
            vp = f10 * p + f11 * v
            e = zz - (h0 * pp + h1 * vp)
            p = pp + K[t, 0, 0] * e
            v = vp + K[t, 1, 0] * e
            out[b, t, o] = p
            out[b, t, o + 1] = v
        if t0 < L:
            x = np.empty(2)
            x[0] = p
            x[1] = v
            P = P0.copy() if t0 == 0 else Pf[t0 - 1].copy()
            for t in range(t0, L):
                _kf_full_update(F, H, Q, R, x, P, z[b, t], a)
                out[b, t, o] = x[0]
                out[b, t, o + 1] = x[1]
        for t in range(L, T):
            out[b, t, o] = np.nan
            out[b, t, o + 1] = np.nan


@nb.njit(**_OPTS)
def fir_kernel(z, out, C, lengths, axes, bad):
    """x(k/k) = sum_{j < min(M, k)} C_j z(k-j), C_j = A^j B (seed 000 eq. 22, truncated warm-up).

    ``bad[b]`` is set to 1 + the first time index with a NaN measurement of track b.
    """
    nb_, T = z.shape[0], z.shape[1]
    M, n, m = C.shape[0], C.shape[1], C.shape[2]
    for i in nb.prange(nb_ * axes):
        b = i // axes
        zo = (i - b * axes) * m
        xo = (i - b * axes) * n
        L = lengths[b]
        x = np.empty(n)
        for t in range(L):
            for r in range(n):
                x[r] = 0.0
            for j in range(min(M, t + 1)):
                for r in range(n):
                    s = 0.0
                    for c in range(m):
                        s += C[j, r, c] * z[b, t - j, zo + c]
                    x[r] += s
            for r in range(n):
                out[b, t, xo + r] = x[r]
            if bad[b] == 0:
                for c in range(m):
                    if np.isnan(z[b, t, zo + c]):
                        bad[b] = t + 1
        for t in range(L, T):
            for r in range(n):
                out[b, t, xo + r] = np.nan


@nb.njit(**_OPTS)
def matvec_kernel(x, out, M, axes):
    """out[b, t] = M x[b, t] per axis block (N-step prediction x(k+N/k) = F^N x(k/k))."""
    nb_, T = x.shape[0], x.shape[1]
    n = M.shape[0]
    for i in nb.prange(nb_ * axes):
        b = i // axes
        o = (i - b * axes) * n
        for t in range(T):
            for r in range(n):
                s = 0.0
                for c in range(n):
                    s += M[r, c] * x[b, t, o + c]
                out[b, t, o + r] = s


@nb.njit(**_OPTS)
def copy_kernel(src, dst):
    """The memory-copy baseline: dst[i] = src[i], parallel over the same two cores."""
    N = src.shape[0]
    nchunk = 64
    step = (N + nchunk - 1) // nchunk
    for k in nb.prange(nchunk):
        lo = k * step
        hi = min(N, lo + step)
        for i in range(lo, hi):
            dst[i] = src[i]
