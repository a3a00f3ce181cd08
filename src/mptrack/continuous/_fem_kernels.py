"""Compiled prediction steps of the grid filter on a LAPACK band LU (see ``_fem._factorise``).

The factors are those of ``?gbtrf`` with kl = ku, stored transposed so that
each column of the band is a contiguous row: ``F[j, r] = ab[r, j]`` with
``ab`` LAPACK's (3·kl + 1, n) band array, and ``piv`` the 0-based row
interchanges scipy returns.  Solves run in the factors' precision (single, see
``_fem._SOLVE_DTYPE``); the density and the element matrix-vector products
stay double.  Kernels are compiled on first use and cached on disk.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import _jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from ._kernels import _BLOCK, _as_kernel, _flow

__all__ = ["band_solve", "band_sdirk2", "band_cn", "deposit", "interpolate", "push_points", "flow_points",
           "cholesky_solve", "band_cholesky"]


@njit(cache=True)
def band_solve(F, piv, kl, b):
    """Overwrite b with B⁻¹b, B = P L U from ?gbtrf (what ?gbtrs does for one right-hand side)."""
    n = b.shape[0]
    kv = 2 * kl
    for j in range(n - 1):  # L: forward, with the row interchanges
        lm = min(kl, n - j - 1)
        r = piv[j]
        bj = b[r]
        if r != j:
            b[r] = b[j]
            b[j] = bj
        col = F[j, kv + 1:kv + 1 + lm]
        seg = b[j + 1:j + 1 + lm]
        for i in range(lm):
            seg[i] -= col[i] * bj
    for j in range(n - 1, -1, -1):  # U (kv superdiagonals): backward, column by column
        bj = b[j] / F[j, kv]
        b[j] = bj
        lo = max(0, j - kv)
        col = F[j, kv + lo - j:kv]
        seg = b[lo:j]
        for i in range(j - lo):
            seg[i] -= col[i] * bj
    return b


@njit(cache=True)
def cholesky_solve(C, kd, b):
    """Overwrite b with B⁻¹b, B = L Lᵀ with L from ?pbtrf (lower, half-bandwidth kd), stored twice so
    that both triangular solves run over contiguous memory: C (n, 2(kd + 1)) holds column j of L in
    C[j, :kd + 1] (C[j, i] = L[j + i, j]) and row j in C[j, kd + 1:] (C[j, kd + 1 + k] = L[j, j − kd + k])."""
    n = b.shape[0]
    r = kd + 1
    for j in range(n):  # L y = b, column by column
        bj = b[j] / C[j, 0]
        b[j] = bj
        m = min(kd, n - 1 - j)
        col = C[j, 1:1 + m]
        seg = b[j + 1:j + 1 + m]
        for i in range(m):
            seg[i] -= col[i] * bj
    for j in range(n - 1, -1, -1):  # Lᵀ x = y, by the columns of Lᵀ (the rows of L)
        bj = b[j] / C[j, r + kd]
        b[j] = bj
        lo = max(0, j - kd)
        row = C[j, r + lo - (j - kd):r + kd]
        seg = b[lo:j]
        for i in range(j - lo):
            seg[i] -= row[i] * bj
    return b


@njit(cache=True)
def band_cholesky(C, kd):
    """Factorise in place the symmetric positive definite band matrix B (half-bandwidth kd) given by
    its lower band in C[:, :kd + 1] (C[j, i] = B[j + i, j]) into the layout of ``cholesky_solve``
    (right-looking: each column scaled, then its rank-one update of the columns below, all over
    contiguous rows).  Returns False when B is not (numerically) positive definite."""
    n = C.shape[0]
    r = kd + 1
    for j in range(n):
        d = C[j, 0]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        C[j, 0] = d
        C[j, r + kd] = d
        m = min(kd, n - 1 - j)
        for i in range(1, m + 1):
            C[j, i] /= d
            C[j + i, r + kd - i] = C[j, i]  # row j + i of L
        for k in range(1, m + 1):
            ljk = C[j, k]
            row = C[j + k, :m + 1 - k]
            src = C[j, k:m + 1]
            for i in range(m + 1 - k):
                row[i] -= src[i] * ljk
    return True


@njit(cache=True)
def _element_matvec(conn, Ke, x, out):
    """out = K x for K assembled from element matrices Ke (E, 8, 8) on connectivity conn (E, 8);
    Ke (1, 8, 8): the same matrix for every element."""
    out[:] = 0.0
    shared = Ke.shape[0] == 1
    for e in range(conn.shape[0]):
        k = 0 if shared else e
        for a in range(8):
            s = 0.0
            for c in range(8):
                s += Ke[k, a, c] * x[conn[e, c]]
            out[conn[e, a]] += s


@njit(cache=True)
def _solve_into(F, piv, kl, b, work):
    """b ← B⁻¹b, solving in the factors' precision (``work`` has F's dtype); F, piv, kl: a band LU
    (``band_solve``), or a band Cholesky factor (``cholesky_solve``'s C, kl its half-bandwidth) when piv
    is empty."""
    work[:] = b
    if piv.shape[0] == 0:
        cholesky_solve(F, kl, work)
    else:
        band_solve(F, piv, kl, work)
    b[:] = work


@njit(cache=True)
def band_sdirk2(F, piv, kl, conn, Ae, p, tau, gamma, substeps):
    """``substeps`` SDIRK2 steps of M dp/dt = A p (A from element matrices Ae, see _element_matvec);
    F, piv factorise M − γτA (see _solve_into)."""
    p = p.copy()
    n = p.shape[0]
    k1, k2, y = np.empty(n), np.empty(n), np.empty(n)
    work = np.empty(n, F.dtype)
    a = (1.0 - gamma) * tau
    for _ in range(substeps):
        _element_matvec(conn, Ae, p, k1)
        _solve_into(F, piv, kl, k1, work)
        for i in range(n):
            y[i] = p[i] + a * k1[i]
        _element_matvec(conn, Ae, y, k2)
        _solve_into(F, piv, kl, k2, work)
        for i in range(n):
            p[i] += a * k1[i] + gamma * tau * k2[i]
    return p


@njit(cache=True)
def band_cn(F, piv, kl, conn, Re, p, substeps):
    """``substeps`` Crank–Nicolson steps p ← B⁻¹ R p (R = M + τA/2 from element matrices Re;
    F, piv factorise M − τA/2)."""
    p = p.copy()
    q = np.empty(p.shape[0])
    work = np.empty(p.shape[0], F.dtype)
    for _ in range(substeps):
        _element_matvec(conn, Re, p, q)
        _solve_into(F, piv, kl, q, work)
        p, q = q, p
    return p


@njit(cache=True)
def _locate(Y, k, lo, h, n1, n2, N):
    """Element index of point Y[k] in the grid [lo, lo + h·(n1, n2)] (−1 outside, NaN included) and
    the 8 serendipity shape functions there (``_fem.shape_functions``) written into N."""
    u = (Y[k, 0] - lo[0]) / h[0]
    v = (Y[k, 1] - lo[1]) / h[1]
    if not (u >= 0.0 and u <= n1 and v >= 0.0 and v <= n2):
        return -1
    e1 = min(int(u), n1 - 1)
    e2 = min(int(v), n2 - 1)
    x = 2.0 * (u - e1) - 1.0
    y = 2.0 * (v - e2) - 1.0
    N[0] = 0.25 * (1.0 - x) * (1.0 - y) * (-x - y - 1.0)
    N[1] = 0.25 * (1.0 + x) * (1.0 - y) * (x - y - 1.0)
    N[2] = 0.25 * (1.0 + x) * (1.0 + y) * (x + y - 1.0)
    N[3] = 0.25 * (1.0 - x) * (1.0 + y) * (-x + y - 1.0)
    N[4] = 0.5 * (1.0 - x * x) * (1.0 - y)
    N[5] = 0.5 * (1.0 + x) * (1.0 - y * y)
    N[6] = 0.5 * (1.0 - x * x) * (1.0 + y)
    N[7] = 0.5 * (1.0 - x) * (1.0 - y * y)
    return e1 * n2 + e2


@njit(cache=True)
def deposit(Y, w, lo, h, n1, n2, conn, out):
    """out[j] += Σₖ wₖ φⱼ(Yₖ) over the points Yₖ (P, 2) inside the grid [lo, lo + h·(n1, n2)];
    returns the weight of the points outside it (NaN points count as outside)."""
    N = np.empty(8)
    outside = 0.0
    for k in range(Y.shape[0]):
        e = _locate(Y, k, lo, h, n1, n2, N)
        if e < 0:
            outside += w[k]
            continue
        for a in range(8):
            out[conn[e, a]] += w[k] * N[a]
    return outside


@njit(cache=True)
def interpolate(Y, lo, h, n1, n2, conn, p, out):
    """out[k] = the interpolant of nodal values p at Yₖ (P, 2); zero outside the grid."""
    N = np.empty(8)
    for k in range(Y.shape[0]):
        e = _locate(Y, k, lo, h, n1, n2, N)
        s = 0.0
        if e >= 0:
            for a in range(8):
                s += N[a] * p[conn[e, a]]
        out[k] = s
    return out


@njit(cache=True)
def push_points(p, conn, phi, wq, loc, lo, h, n1, n2, rel):
    """The transport's quadrature on a grid [lo, lo + h·(n1, n2)] with nodal values p: on every
    element e (conn (E, 8), row-major over (e1, e2)) the points x = lo + h·((e1, e2) + loc[k]) (loc
    (K, 2) in [0, 1]²) carrying mass w = (Σₐ p[conn[e, a]] φₐ(k)) · wq[k] (phi (K, 8), wq (K,)
    including the element area).  Returns (X (P, 2), w (P,)) of the points with
    |w| > rel · max |w|, in element-major order (``_fem._push``'s NumPy arithmetic)."""
    E, K = conn.shape[0], phi.shape[0]
    w = np.empty(E * K)
    big = 0.0
    for e in range(E):
        for k in range(K):
            s = 0.0
            for a in range(8):
                s += p[conn[e, a]] * phi[k, a]
            v = s * wq[k]
            w[e * K + k] = v
            big = max(big, abs(v))
    cut = rel * big
    count = 0
    for i in range(E * K):
        count += abs(w[i]) > cut
    X = np.empty((count, 2))
    out = np.empty(count)
    i = 0
    for e in range(E):
        u0, u1 = float(e // n2), float(e % n2)
        for k in range(K):
            v = w[e * K + k]
            if abs(v) > cut:
                X[i, 0] = lo[0] + h[0] * (u0 + loc[k, 0])
                X[i, 1] = lo[1] + h[1] * (u1 + loc[k, 1])
                out[i] = v
                i += 1
    return X, out


@njit(cache=True)
def _stiffness(X, drift, params):
    """max over the points X (P, 2) of the Frobenius norm of the drift's Jacobian by central
    differences with step d = 1e-5·max(1, max |X|) (``_fem._flow_steps``'s NumPy arithmetic)."""
    P = X.shape[0]
    big = 1.0
    for i in range(P):
        big = max(big, abs(X[i, 0]), abs(X[i, 1]))
    d = 1e-5 * big
    B = _BLOCK
    Y, F = np.empty((2, 4 * B)), np.empty((2, 4 * B))
    stiff = 0.0
    for start in range(0, P, B):
        nb = min(B, P - start)
        for j in range(4 * B):  # a short last block repeats its last point
            x = X[start + min(j % B, nb - 1)]
            Y[0, j] = x[0]
            Y[1, j] = x[1]
        for j in range(B):
            Y[0, j] = Y[0, j] + d
            Y[0, B + j] = Y[0, B + j] + (-d)
            Y[1, 2 * B + j] = Y[1, 2 * B + j] + d
            Y[1, 3 * B + j] = Y[1, 3 * B + j] + (-d)
        drift(Y, params, F)
        for j in range(nb):
            a0 = F[0, j] - F[0, B + j]
            a1 = F[1, j] - F[1, B + j]
            c0 = F[0, 2 * B + j] - F[0, 3 * B + j]
            c1 = F[1, 2 * B + j] - F[1, 3 * B + j]
            stiff = max(stiff, np.sqrt((a0 * a0 + c0 * c0) + (a1 * a1 + c1 * c1)))
    return stiff / (2.0 * d)


@njit(cache=True)
def flow_points(X, drift_c, drift_jit, params, duration, dt, cap):
    """Carry the points X (P, 2) in place by the noise-free drift flow over ``duration``: as many
    capped RK4 steps as the drift's stiffness at the points needs (``_fem._flow_steps``), the
    drift given by its addresses; returns the number of steps."""
    drift = _as_kernel(drift_c, drift_jit)
    stiff = _stiffness(X, drift, params)
    steps = max(int(np.ceil(2.0 * duration / dt)), int(np.ceil(duration * stiff)), 1)
    _flow(X, drift, params, duration / steps, steps, cap)
    return steps
