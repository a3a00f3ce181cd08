"""Compiled steps of the grid filter (``_fem``).

Galerkin schemes: time steps on a LAPACK band LU (see ``_fem_schemes._factorise``).  The factors are
those of ``?gbtrf`` with kl = ku, stored transposed so that each column of the band is a
contiguous row: ``F[j, r] = ab[r, j]`` with ``ab`` LAPACK's (3·kl + 1, n) band array, and ``piv``
the 0-based row interchanges scipy returns.  Solves run in the factors' precision (single, see
``_fem_schemes._SOLVE_DTYPE``); the density and the element matrix-vector products stay double.

The characteristics scheme: band Cholesky factorisations and solves, the diffusion's SDIRK2
steps (``diffuse``), and the transport compiled end to end (``transport_split``: grid placement,
flow, quadrature, deposit, mass solve), built from pieces the NumPy-flow path of a model without
kernels calls one by one; the search for the posterior's modes (``lattice_modes``).  Per-point
helpers take and return scalars: a helper called per point with array arguments costs a
reference count per array and call (it made the deposit 8× slower).  Kernels are compiled on
first use and cached on disk.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from ._kernels import _BLOCK, _as_kernel, _flow

__all__ = ["band_solve", "band_sdirk2", "band_cn", "deposit", "interpolate", "flow_points", "cholesky_solve",
           "band_cholesky", "element_band_cholesky", "clip_normalise", "grid_moments", "sigma_points_2d", "predicted_box",
           "next_grid", "flow_sites", "transport_deposit", "mass_solve", "place_grid", "carry", "transport_split", "within", "stiffness_unit",
           "diffuse_kept", "predict_dt", "lattice_modes",
           "second_difference_max"]


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
def element_band_cholesky(Be, conn, kd, C):
    """Assemble the lower band of the matrix B = Σₑ Be on every element of conn (E, 8) (one element
    matrix Be (8, 8) for all) into C[:, :kd + 1] (C[j, i] = B[j + i, j]; C zero on entry, dtype of the
    factor), then factorise it in place (``band_cholesky``).  Returns False when B is not (numerically)
    positive definite."""
    for e in range(conn.shape[0]):
        for a in range(8):
            i = conn[e, a]
            for c in range(8):
                j = conn[e, c]
                if i >= j:
                    C[j, i - j] += Be[a, c]
    return band_cholesky(C, kd)


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
def _locate(Y0, Y1, lo, h, n1, n2):
    """(element (P,), ξ (P,), η (P,)) of the points (Y0[i], Y1[i]) in the grid [lo, lo + h·(n1, n2)]: the
    element index (−1 outside, NaN included) and the point's coordinates in [−1, 1]² there.  Branch-free
    over the points, so that the loop vectorises."""
    P = Y0.shape[0]
    el, xs, ys = np.empty(P, np.int64), np.empty(P), np.empty(P)
    r0, r1 = 1.0 / h[0], 1.0 / h[1]
    for i in range(P):
        u = (Y0[i] - lo[0]) * r0
        v = (Y1[i] - lo[1]) * r1
        inside = (u >= 0.0) & (u <= n1) & (v >= 0.0) & (v <= n2)
        e1 = min(int(u), n1 - 1) if inside else 0
        e2 = min(int(v), n2 - 1) if inside else 0
        el[i] = e1 * n2 + e2 if inside else -1
        xs[i] = 2.0 * (u - e1) - 1.0
        ys[i] = 2.0 * (v - e2) - 1.0
    return el, xs, ys


@njit(cache=True)
def _serendipity(x, y):
    """The 8 serendipity shape functions at (ξ, η) = (x, y) (``_fem.shape_functions``)."""
    return (0.25 * (1.0 - x) * (1.0 - y) * (-x - y - 1.0), 0.25 * (1.0 + x) * (1.0 - y) * (x - y - 1.0),
            0.25 * (1.0 + x) * (1.0 + y) * (x + y - 1.0), 0.25 * (1.0 - x) * (1.0 + y) * (-x + y - 1.0),
            0.5 * (1.0 - x * x) * (1.0 - y), 0.5 * (1.0 + x) * (1.0 - y * y),
            0.5 * (1.0 - x * x) * (1.0 + y), 0.5 * (1.0 - x) * (1.0 - y * y))


@njit(cache=True)
def deposit(Y, w, lo, h, n1, n2, conn, out):
    """out[j] += Σₖ wₖ φⱼ(Yₖ) over the points Yₖ (P, 2) inside the grid [lo, lo + h·(n1, n2)];
    returns the weight of the points outside it (NaN points count as outside)."""
    el, xs, ys = _locate(Y[:, 0], Y[:, 1], lo, h, n1, n2)
    return _scatter(el, xs, ys, w, conn, out)


@njit(cache=True)
def _scatter(el, xs, ys, w, conn, out):
    """out[j] += Σₖ wₖ φⱼ at the located points (``_locate``); returns the weight of those outside."""
    outside = 0.0
    for k in range(el.shape[0]):
        e = el[k]
        if e < 0:
            outside += w[k]
            continue
        N = _serendipity(xs[k], ys[k])
        for a in range(8):
            out[conn[e, a]] += w[k] * N[a]
    return outside


@njit(cache=True)
def interpolate(Y, lo, h, n1, n2, conn, p, out):
    """out[k] = the interpolant of nodal values p at Yₖ (P, 2); zero outside the grid."""
    el, xs, ys = _locate(Y[:, 0], Y[:, 1], lo, h, n1, n2)
    for k in range(el.shape[0]):
        s = 0.0
        if el[k] >= 0:
            N = _serendipity(xs[k], ys[k])
            for a in range(8):
                s += N[a] * p[conn[el[k], a]]
        out[k] = s
    return out


@njit(cache=True)
def _stiffness(X, drift, params):
    """max over the points X (P, 2) of the Frobenius norm of the drift's Jacobian by central
    differences with step d = 1e-5·max(1, max |X|) (``_fem_schemes._flow_steps``'s NumPy arithmetic)."""
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
    capped RK4 steps as the drift's stiffness at the points needs (``_fem_schemes._flow_steps``), the
    drift given by its addresses; returns the number of steps."""
    drift = _as_kernel(drift_c, drift_jit)
    stiff = _stiffness(X, drift, params)
    steps = max(int(np.ceil(2.0 * duration / dt)), int(np.ceil(duration * stiff)), 1)
    _flow(X, drift, params, duration / steps, steps, cap)
    return steps



# ---------------------------------------------------------------- the characteristics scheme's steps
@njit(cache=True)
def clip_normalise(p, V0, area):
    """In place: negative nodal values set to zero, then p divided by its mass area·(V0 · p) (the
    interpolant's integral, ``FEMGrid.W0 = area·V0``).  Returns (the negative mass removed, the mass
    before dividing); a mass that is not positive and finite leaves p undivided (the caller raises)."""
    clipped = 0.0
    mass = 0.0
    for j in range(p.shape[0]):
        if p[j] < 0.0:
            clipped -= V0[j] * p[j]
            p[j] = 0.0
        mass += V0[j] * p[j]
    mass *= area
    if mass > 0.0 and mass < np.inf:
        for j in range(p.shape[0]):
            p[j] /= mass
    return clipped * area, mass


@njit(cache=True)
def grid_moments(p, V0, V1, V2, lo, h):
    """(mass, mean (2,), covariance (2, 2)) of the interpolant of p on the grid with corner lo and
    element sides h, from the unit-element moment weights V0 (N,), V1 (N, 2), V2 (N, 3)
    (``FEMGrid.moments``: computed in element units, then mapped back)."""
    m0 = 0.0
    u = np.zeros(2)
    s = np.zeros(3)
    for j in range(p.shape[0]):
        m0 += V0[j] * p[j]
        u[0] += V1[j, 0] * p[j]
        u[1] += V1[j, 1] * p[j]
        s[0] += V2[j, 0] * p[j]
        s[1] += V2[j, 1] * p[j]
        s[2] += V2[j, 2] * p[j]
    u /= m0
    s /= m0
    cross = s[1] - u[0] * u[1]
    mean = lo + h * u
    cov = np.empty((2, 2))
    cov[0, 0] = (s[0] - u[0] * u[0]) * (h[0] * h[0])
    cov[0, 1] = cross * (h[0] * h[1])
    cov[1, 0] = cov[0, 1]
    cov[1, 1] = (s[2] - u[1] * u[1]) * (h[1] * h[1])
    return (h[0] * h[1]) * m0, mean, cov


@njit(cache=True)
def psd_project_2d(P):
    """P (2, 2) symmetrised and projected onto the PSD cone (eigenvalues clipped at zero): the moments
    of a coarse grid's density with clipped negative lobes need not be PSD.  A non-finite P is
    returned as it is (:func:`sigma_points_2d` then refuses it)."""
    A = 0.5 * (P + P.T)
    if not np.all(np.isfinite(A)):
        return A
    w, V = np.linalg.eigh(A)
    if w[0] >= 0.0:
        return A
    out = np.zeros((2, 2))
    for i in range(2):
        r = max(w[i], 0.0)
        for a in range(2):
            for b in range(2):
                out[a, b] += V[a, i] * r * V[b, i]
    return out


@njit(cache=True)
def sigma_points_2d(m, P, c, X):
    """X (5, 2) ← the sigma points m, m ± columns of √(cP) (``mptrack.nonlinear.sigma_points``: a Cholesky
    factor, else the eigen-decomposition with eigenvalues clipped at zero).  Returns False when cP is
    not positive semi-definite (an eigenvalue below −1e-9 of the largest) or not finite."""
    a, b, d = c * P[0, 0], c * P[0, 1], c * P[1, 1]
    if not (np.isfinite(a) and np.isfinite(b) and np.isfinite(d) and np.isfinite(m[0]) and np.isfinite(m[1])):
        return False
    S = np.zeros((2, 2))
    t = d - (b / np.sqrt(a)) ** 2 if a > 0.0 else -1.0
    if a > 0.0 and t > 0.0:
        S[0, 0] = np.sqrt(a)
        S[1, 0] = b / S[0, 0]
        S[1, 1] = np.sqrt(t)
    else:
        w, V = np.linalg.eigh(np.array([[a, b], [b, d]]))
        if w[0] < -1e-9 * max(abs(w[1]), 1e-300):
            return False
        for i in range(2):
            r = np.sqrt(max(w[i], 0.0))
            S[0, i] = V[0, i] * r
            S[1, i] = V[1, i] * r
    for r in range(2):
        X[0, r] = m[r]
        for i in range(2):
            X[1 + i, r] = m[r] + S[r, i]
            X[3 + i, r] = m[r] - S[r, i]
    return True


@njit(cache=True)
def predicted_box(Y, Wm, Wc, Qd, duration, width, floor, lo, hi):
    """lo, hi ← the predicted mean ± width·σ from the flowed sigma points Y (5, 2) with weights Wm, Wc:
    σ² = Wc·(Y − mean)² + Q_ii·duration, σ floored at ``floor``."""
    for r in range(2):
        mp = 0.0
        for k in range(Y.shape[0]):
            mp += Wm[k] * Y[k, r]
        var = 0.0
        for k in range(Y.shape[0]):
            var += Wc[k] * (Y[k, r] - mp) ** 2
        sp = max(np.sqrt(max(var + Qd[r] * duration, 0.0)), floor)
        lo[r] = mp - width * sp
        hi[r] = mp + width * sp


@njit(cache=True)
def next_grid(blo, bhi, lo, hi, margin, shrink, new_lo, new_hi):
    """The next grid around the box [blo, bhi] widened by ``margin`` of its size on each side: centred on
    it, with the current grid's sides (lo, hi) while the widened box's sides lie within [shrink, 1] of
    them on both axes (a translated grid), else the widened box's own."""
    keep = True
    for r in range(2):
        need = (1.0 + 2.0 * margin) * (bhi[r] - blo[r])
        old = hi[r] - lo[r]
        keep = keep and need <= old and need >= shrink * old
    for r in range(2):
        size = hi[r] - lo[r] if keep else (1.0 + 2.0 * margin) * (bhi[r] - blo[r])
        centre = 0.5 * (blo[r] + bhi[r])
        new_lo[r] = centre - 0.5 * size
        new_hi[r] = centre + 0.5 * size


@njit(cache=True)
def flow_sites(lo, h, lattice, n1, n2):
    """The points whose flow the transport interpolates: the grid's nodes (lattice (N, 2) on the
    half-element lattice), then the centres of its elements (row-major over (e1, e2))."""
    N = lattice.shape[0]
    Z = np.empty((N + n1 * n2, 2))
    for j in range(N):
        Z[j, 0] = lo[0] + 0.5 * h[0] * lattice[j, 0]
        Z[j, 1] = lo[1] + 0.5 * h[1] * lattice[j, 1]
    for e in range(n1 * n2):
        Z[N + e, 0] = lo[0] + h[0] * ((e // n2) + 0.5)
        Z[N + e, 1] = lo[1] + h[1] * ((e % n2) + 0.5)
    return Z


# serendipity shape functions at the element centre (ξ = η = 0): corners −¼, mid-sides ½
_CENTRE = np.array([-0.25, -0.25, -0.25, -0.25, 0.5, 0.5, 0.5, 0.5])


@njit(cache=True)
def transport_deposit(p, conn, lo, h, n2, loc, phi, wq, bounds, levels, Z, tol, rel, new_lo, new_h, new_n1, new_n2,
                      new_conn, b):
    """The transport's quadrature on the grid (corner lo, element sides h, n2 elements along the second
    axis) with nodal values p, deposited where the flow takes it on the new grid (corner new_lo, element
    sides new_h, new_n1 × new_n2 elements, connectivity new_conn): b_j += Σ w φ_j(Y).

    Every element e (conn (E, 8), row-major) carries points x = lo + h·((e1, e2) + loc[k]) with mass
    w = (Σₐ p[conn[e, a]] φₐ(k))·wq[k]·h1·h2 by one of the quadrature rules stacked in loc (K, 2) in
    [0, 1]², phi (K, 8), wq (K,) (on a unit element; rule r is rows bounds[r] .. bounds[r + 1] − 1, from
    the finest): rule r = how many of the decreasing ``levels`` (× max p) exceed all the element's nodal
    values; points with |w| ≤ rel × max |w| are dropped.  The flow
    takes a point to Y = Σₐ φₐ(k) Z[conn[e, a]], the serendipity interpolant of the flowed nodes Z[:N]
    (an isoparametric map), except on the elements where that interpolant misses the flowed centre
    Z[N + e] by more than ``tol`` of a new element: their points are returned for an exact flow instead
    of deposited.  Returns (the weight that fell outside the new grid, the total weight, X (M, 2) and
    w (M,) of the points to flow exactly)."""
    E, N = conn.shape[0], p.shape[0]
    phiT = np.ascontiguousarray(phi.T)   # (8, K): the points of a rule contiguous, the loops below vectorise
    pmax = 0.0
    for j in range(N):
        pmax = max(pmax, abs(p[j]))
    first = np.empty(E, np.int64)    # each element's rule: rows first[e] .. last[e] − 1
    last = np.empty(E, np.int64)
    bad = np.empty(E, np.bool_)
    start = np.empty(E + 1, np.int64)
    start[0] = 0
    for e in range(E):
        big = 0.0
        ex, ey = Z[N + e, 0], Z[N + e, 1]
        for a in range(8):
            big = max(big, abs(p[conn[e, a]]))
            ex -= _CENTRE[a] * Z[conn[e, a], 0]
            ey -= _CENTRE[a] * Z[conn[e, a], 1]
        r = 0
        while r < levels.shape[0] and big < levels[r] * pmax:
            r += 1
        first[e], last[e] = bounds[r], bounds[r + 1]
        bad[e] = not (max(abs(ex) / new_h[0], abs(ey) / new_h[1]) <= tol)
        start[e + 1] = start[e] + last[e] - first[e]
    P = start[E]
    w, Y0, Y1 = np.zeros(P), np.zeros(P), np.zeros(P)   # each point's weight and image
    area = h[0] * h[1]
    for e in range(E):
        i0, f0 = start[e] - first[e], first[e]
        for a in range(8):
            pa, za0, za1 = p[conn[e, a]], Z[conn[e, a], 0], Z[conn[e, a], 1]
            for k in range(f0, last[e]):
                v = phiT[a, k]
                w[i0 + k] += pa * v
                Y0[i0 + k] += za0 * v
                Y1[i0 + k] += za1 * v
        for k in range(f0, last[e]):
            w[i0 + k] *= wq[k] * area
    big = 0.0
    n_exact = 0
    for e in range(E):
        for i in range(start[e], start[e + 1]):
            big = max(big, abs(w[i]))
        if bad[e]:
            n_exact += start[e + 1] - start[e]
    cut = rel * big
    for i in range(P):              # the dropped points and those to flow exactly take no part below
        if not abs(w[i]) > cut:
            w[i] = 0.0
    X, wx = np.empty((n_exact, 2)), np.empty(n_exact)
    total = 0.0
    m = 0
    for e in range(E):
        if not bad[e]:
            continue
        u0, u1 = float(e // n2), float(e % n2)
        for i in range(start[e], start[e + 1]):
            if w[i] != 0.0:
                k = first[e] + i - start[e]
                X[m, 0] = lo[0] + h[0] * (u0 + loc[k, 0])
                X[m, 1] = lo[1] + h[1] * (u1 + loc[k, 1])
                wx[m] = w[i]
                total += w[i]
                m += 1
                w[i] = 0.0
    for i in range(P):
        total += w[i]
    el, xs, ys = _locate(Y0, Y1, new_lo, new_h, new_n1, new_n2)
    outside = _scatter(el, xs, ys, w, new_conn, b)
    return outside, total, X[:m].copy(), wx[:m].copy()


@njit(cache=True)
def mass_solve(b, Cm, kdm, h):
    """q with M q = b on a grid of element sides h: M = h1·h2 × the unit mass matrix, whose band
    Cholesky factor is (Cm, kdm)."""
    q = cholesky_solve(Cm, kdm, b.copy())
    area = h[0] * h[1]
    for j in range(q.shape[0]):
        q[j] /= area
    return q


@njit(cache=True)
def place_grid(p, lo, hi, duration, grid, place, flow):
    """The next grid of the characteristics scheme's transport, around the density predicted for
    t + duration from the moments of p on the grid [lo, hi] (sigma points flowed over ``duration``,
    ``predicted_box``, ``next_grid``).  Returns (ok, new lo, new hi): not ok when the moments have no
    sigma points (not positive semi-definite)."""
    n1, n2, V0, V1, V2 = grid[0], grid[1], grid[4], grid[5], grid[6]
    width, c, Wm, Wc, Qd, margin, shrink = place
    drift_c, drift_jit, params, dt, cap = flow
    h = np.empty(2)
    h[0], h[1] = (hi[0] - lo[0]) / n1, (hi[1] - lo[1]) / n2
    new_lo, new_hi = lo.copy(), hi.copy()
    _, m, P = grid_moments(p, V0, V1, V2, lo, h)
    S = np.empty((5, 2))
    if not sigma_points_2d(m, psd_project_2d(P), c, S):
        return False, new_lo, new_hi
    flow_points(S, drift_c, drift_jit, params, duration, dt, cap)
    blo, bhi = np.empty(2), np.empty(2)
    predicted_box(S, Wm, Wc, Qd, duration, width, 0.5 * min(h[0], h[1]), blo, bhi)
    next_grid(blo, bhi, lo, hi, margin, shrink, new_lo, new_hi)
    return True, new_lo, new_hi


@njit(cache=True)
def carry(p, lo, hi, new_lo, new_hi, duration, grid, flow, rules):
    """The density p on the grid [lo, hi] carried by the flow over ``duration`` onto the grid [new_lo,
    new_hi] of the same shape (``flow_sites``, ``transport_deposit``, the exact flow and ``deposit`` of
    the points it returns, ``mass_solve``) and ``clip_normalise``d: (q, lost, clipped, mass)."""
    n1, n2, conn, lattice, V0, Cm, kd = grid[0], grid[1], grid[2], grid[3], grid[4], grid[7], grid[8]
    drift_c, drift_jit, params, dt, cap = flow
    loc, phi, wq, bounds, levels, tol = rules
    h, hn = np.empty(2), np.empty(2)
    h[0], h[1] = (hi[0] - lo[0]) / n1, (hi[1] - lo[1]) / n2
    hn[0], hn[1] = (new_hi[0] - new_lo[0]) / n1, (new_hi[1] - new_lo[1]) / n2
    Z = flow_sites(lo, h, lattice, n1, n2)
    flow_points(Z, drift_c, drift_jit, params, duration, dt, cap)
    b = np.zeros(p.shape[0])
    outside, total, X, w = transport_deposit(p, conn, lo, h, n2, loc, phi, wq, bounds, levels, Z, tol, 1e-12, new_lo,
                                             hn, n1, n2, conn, b)
    if X.shape[0]:
        flow_points(X, drift_c, drift_jit, params, duration, dt, cap)
        outside += deposit(X, w, new_lo, hn, n1, n2, conn, b)
    q = mass_solve(b, Cm, kd, hn)
    lost = outside / total if total > 0.0 else 0.0
    clipped, mass = clip_normalise(q, V0, hn[0] * hn[1])
    return q, lost, clipped, mass


@njit(cache=True)
def transport_split(p, lo, hi, moving, duration, grid, place, flow, rules):
    """One transport of the characteristics scheme, compiled end to end (``_fem_schemes._Characteristics``;
    a model without kernels runs the same steps with the NumPy flow in between): on a moving grid the
    next grid (``place_grid``), then the density carried onto it (``carry``).

    grid = (n1, n2, conn, lattice, V0, V1, V2, mass factor, its kd, ...), place = (width, sigma-point
    scale c, Wm, Wc, diag Q, margin, shrink), flow = (drift addresses, params, dt, cap), rules = (loc,
    phi, wq, bounds, levels, tol) of ``transport_deposit``.  Returns (status, new lo, new hi, q, lost,
    clipped, mass): status 1 when the moments have no sigma points (not positive semi-definite)."""
    new_lo, new_hi = lo, hi
    if moving:
        ok, new_lo, new_hi = place_grid(p, lo, hi, duration, grid, place, flow)
        if not ok:
            return 1, new_lo, new_hi, p, 0.0, 0.0, 0.0
    q, lost, clipped, mass = carry(p, lo, hi, new_lo, new_hi, duration, grid, flow, rules)
    return 0, new_lo, new_hi, q, lost, clipped, mass


# ---------------------------------------------------------------- the diffusion on kept factorisations
@njit(cache=True)
def _psd2(d00, d01, d11, eps):
    return d00 >= -eps and d11 >= -eps and d00 * d11 - d01 * d01 >= -eps * eps


@njit(cache=True)
def within(A, B, lo, hi):
    """lo·B ⪯ A ⪯ hi·B for symmetric 2 × 2 A, B ⪰ 0 given as (a00, a01, a11) (to rounding)."""
    eps = 1e-12 * (abs(B[0]) + abs(B[2]))
    t, u = hi + 1e-9, lo - 1e-9
    return (_psd2(t * B[0] - A[0], t * B[1] - A[1], t * B[2] - A[2], eps)
            and _psd2(A[0] - u * B[0], A[1] - u * B[1], A[2] - u * B[2], eps))


@njit(cache=True)
def stiffness_unit(G, s00, s01, s11):
    """Â(S) = ½ Σ_de S_de G_de: the diffusion's element stiffness on a unit element (8, 8) for
    S = H⁻¹QH⁻¹ = [[s00, s01], [s01, s11]], G (3, 8, 8) = ∫ ∂_dφ ∂_eφᵀ for (d, e) = 00, 01, 11."""
    return 0.5 * (s00 * G[0] + s01 * (G[1] + G[1].T) + s11 * G[2])


@njit(cache=True)
def diffuse_kept(kept, p, h, duration, grid, diff):
    """The diffusion over ``duration`` of nodal values p on a grid with element sides h (``_fem_schemes._Characteristics``
    describes the scheme): SDIRK2 in n steps of τ_s (n = ⌈substeps·duration/dt⌉, or with substeps = 0
    ⌈duration·ρ/step⌉, ρ the largest eigenvalue of S = H⁻¹QH⁻¹) on the band Cholesky factorisation of
    M̂ + γ·Â(C) kept for the C' = τ_s·S nearest in time of use with reuse_lo·C ⪯ C' ⪯ reuse_hi·C, or
    on a new one (replacing the least recently used); then ``clip_normalise``.

    kept = (keys (K, 3): each factorisation's C, factors (K, N, 2(kd + 1)), stamps (K,): last use (0:
    empty), counters (2,): [clock, factorisations made]); grid as for ``transport_split`` (conn [2],
    V0 [4], kd [8], unit mass element matrix Me [9], G [10]); diff = (Q (2, 2), substeps, step, dt, γ,
    reuse_lo, reuse_hi).  Returns (q, clipped, mass, status): status 3 when a new stage matrix is not
    positive definite."""
    keys, factors, stamps, counters = kept
    conn, V0, kd, Me, G = grid[2], grid[4], grid[8], grid[9], grid[10]
    Q, substeps, step, dt, gamma, reuse_lo, reuse_hi = diff
    s00, s01, s11 = Q[0, 0] / (h[0] * h[0]), Q[0, 1] / (h[0] * h[1]), Q[1, 1] / (h[1] * h[1])
    if substeps > 0:
        n = max(1, int(np.ceil(substeps * duration / dt - 1e-9)))
    else:
        rho = 0.5 * (s00 + s11) + np.hypot(0.5 * (s00 - s11), s01)
        n = max(1, int(np.ceil(duration * rho / step)))
    tau = duration / n
    C = np.array([tau * s00, tau * s01, tau * s11])
    slot = -1
    for k in range(stamps.shape[0]):   # the most recently used within bounds
        if stamps[k] > 0 and (slot < 0 or stamps[k] > stamps[slot]) and within(keys[k], C, reuse_lo, reuse_hi):
            slot = k
    if slot < 0:                       # a new factorisation, in an empty or the least recently used slot
        slot = 0
        for k in range(1, stamps.shape[0]):
            if stamps[k] < stamps[slot]:
                slot = k
        F = factors[slot]
        F[:] = 0.0
        stamps[slot] = 0
        if not element_band_cholesky(Me + gamma * stiffness_unit(G, C[0], C[1], C[2]), conn, kd, F):
            return p, 0.0, 0.0, 3
        keys[slot] = C
        counters[1] += 1
    counters[0] += 1
    stamps[slot] = counters[0]
    Ae = np.empty((1, 8, 8))
    Ae[0] = -stiffness_unit(G, s00, s01, s11)
    q = band_sdirk2(factors[slot], np.empty(0, np.int32), kd, conn, Ae, p, tau, gamma, n)
    clipped, mass = clip_normalise(q, V0, h[0] * h[1])
    return q, clipped, mass, 0


@njit(cache=True)
def _no_mass(mass):
    return not (mass > 0.0 and mass < np.inf)


@njit(cache=True)
def predict_dt(p, lo, hi, moving, splits, kept, grid, place, flow, rules, diff):
    """One dt of the characteristics scheme, compiled (``_fem_schemes._Characteristics.predict``): a diffusion
    over τ/2 (``diffuse_kept``), then ``splits`` times a transport over τ = dt/splits
    (``transport_split``) and a diffusion over τ (τ/2 after the last).  Returns (status, lo, hi, p, lost,
    clipped): status 1 as for ``transport_split``, 2 when the density has no positive mass left after
    a step, 3 as for ``diffuse_kept``."""
    n1, n2 = grid[0], grid[1]
    tau = flow[3] / splits
    h = np.empty(2)
    h[0], h[1] = (hi[0] - lo[0]) / n1, (hi[1] - lo[1]) / n2
    p, clipped, mass, status = diffuse_kept(kept, p, h, 0.5 * tau, grid, diff)
    lost = 0.0
    for i in range(splits):
        if status == 0 and _no_mass(mass):
            status = 2
        if status:
            break
        status, lo, hi, p, out, c1, mass = transport_split(p, lo, hi, moving, tau, grid, place, flow, rules)
        if status == 0 and _no_mass(mass):
            status = 2
        if status:
            break
        h[0], h[1] = (hi[0] - lo[0]) / n1, (hi[1] - lo[1]) / n2
        p, c2, mass, status = diffuse_kept(kept, p, h, tau if i < splits - 1 else 0.5 * tau, grid, diff)
        lost += out
        clipped += c1 + c2
    if status == 0 and _no_mass(mass):
        status = 2
    return status, lo, hi, p, lost, clipped


# ---------------------------------------------------------------- the posterior's modes (``_fem._split``)
@njit(cache=True)
def lattice_modes(d, lattice, L1, L2, level):
    """The 8-connected regions of the half-spacing lattice (L1 × L2) where the image of the nodal values
    d (at ``lattice`` (N, 2); the element centres, which have no node, get the mean of their four
    mid-side neighbours) exceeds ``level`` × its maximum, labelled in raster order (as
    scipy.ndimage.label).  Returns (count, stats (count, 5)): each region's Σw, Σw·i, Σw·j, Σw·i²,
    Σw·j² over its lattice points (i, j) with weights w = the image there."""
    img = np.zeros((L1, L2))
    for k in range(lattice.shape[0]):
        img[lattice[k, 0], lattice[k, 1]] = d[k]
    for i in range(1, L1 - 1, 2):
        for j in range(1, L2 - 1, 2):
            img[i, j] = 0.25 * (img[i - 1, j] + img[i + 1, j] + img[i, j - 1] + img[i, j + 1])
    cut = level * img.max()
    label = np.full((L1, L2), -1, np.int64)
    stack = np.empty(L1 * L2, np.int64)
    stats = np.zeros((L1 * L2 // 2 + 1, 5))
    count = 0
    for i0 in range(L1):
        for j0 in range(L2):
            if label[i0, j0] >= 0 or not img[i0, j0] > cut:
                continue
            label[i0, j0] = count
            top = 0
            stack[0] = i0 * L2 + j0
            top = 1
            while top > 0:
                top -= 1
                i, j = stack[top] // L2, stack[top] % L2
                w = img[i, j]
                stats[count, 0] += w
                stats[count, 1] += w * i
                stats[count, 2] += w * j
                stats[count, 3] += w * i * i
                stats[count, 4] += w * j * j
                for a in range(max(i - 1, 0), min(i + 2, L1)):
                    for b in range(max(j - 1, 0), min(j + 2, L2)):
                        if label[a, b] < 0 and img[a, b] > cut:
                            label[a, b] = count
                            stack[top] = a * L2 + b
                            top += 1
            count += 1
    return count, stats[:count].copy()


@njit(cache=True)
def second_difference_max(d, logl, a, b, c, level):
    """max |logl[a] − 2 logl[b] + logl[c]| over the node triples (a, b, c) where d[b] > level × max d
    (0 when there are none)."""
    cut = level * d.max()
    big = 0.0
    for k in range(b.shape[0]):
        if d[b[k]] > cut:
            big = max(big, abs(logl[a[k]] - 2.0 * logl[b[k]] + logl[c[k]]))
    return big
