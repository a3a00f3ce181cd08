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

__all__ = ["band_solve", "band_sdirk2", "band_cn", "deposit", "interpolate"]


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
def _element_matvec(conn, Ke, x, out):
    """out = K x for K assembled from element matrices Ke (E, 8, 8) on connectivity conn (E, 8)."""
    out[:] = 0.0
    for e in range(conn.shape[0]):
        for a in range(8):
            s = 0.0
            for c in range(8):
                s += Ke[e, a, c] * x[conn[e, c]]
            out[conn[e, a]] += s


@njit(cache=True)
def _solve_into(F, piv, kl, b, work):
    """b ← B⁻¹b, solving in the factors' precision (``work`` has F's dtype)."""
    work[:] = b
    band_solve(F, piv, kl, work)
    b[:] = work


@njit(cache=True)
def band_sdirk2(F, piv, kl, conn, Ae, p, tau, gamma, substeps):
    """``substeps`` SDIRK2 steps of M dp/dt = A p (A from element matrices Ae); F, piv factorise M − γτA."""
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
