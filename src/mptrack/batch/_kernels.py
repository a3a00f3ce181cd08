"""Compiled (numba) kernels of the batch engine.

Layout: measurements ``z`` (B, T, m_total) and states ``out`` (B, T, n_total),
C-contiguous, float64 or float32.  The parallel loop runs over *tracks*
(``prange``); each track is one sequential recursion over time that reads one
contiguous stream of ``z`` and writes one contiguous stream of ``out``, so
each thread streams through memory front to back (hardware prefetch friendly)
and never shares a cache line with another thread except at track borders.

Axes as extra batch (model B run per axis, Assimakis & Adam 2014, eqs. 17-18): a track is
the pair (b, a) with ``a < axes``; it reads columns ``a*m .. a*m+m-1`` of
``z[b]`` and writes columns ``a*n .. a*n+n-1`` of ``out[b]``.  ``axes = 1`` is
the plain joint model.  The n = 2, m = 1 block kernels also run the axes of a block-diagonal joint
model (model A) this way, each with its own blocks of the model's matrices.

A track with its own covariance (the KF after its first gap) runs the one compiled
predict/update of :mod:`mptrack._core.kalman` (:func:`own_step`).  The shared-gain paths are the
documented exception: complete steps run x = A(k) x + K(k) z with the shared gains -- in the generic
kernels four tracks side by side in small arrays (:func:`_lane_steps`); tests/test_kalman_core.py
checks them against the core.  Rows of k axes of n = 2, m = 1 (model B on z (B, T, 1), per axis, the
axes of a block-diagonal model such as model A) run in *time blocks*: each axis eight steps at a time
as vectors (``ss_kernel_blocks``, ``kf_kernel_blocks``, docs/decisions/2026-11-23-batch-engine.md "Time blocks"), with scalar
steps (:func:`_ss21_steps`, :func:`_kf21_track`) for blocks with a gap and a row's last steps.

The state is carried in float64 whatever the storage dtype; float32 only
halves the bytes streamed.  Steps ``t >= lengths[b]`` are written as NaN.

The filters' kernels also do the finiteness checks of their data while they stream it (a separate
pass over z and one over the output cost as much as the filter, docs/decisions/2026-11-23-batch-engine.md "Checks fused into
the kernels"): each returns the number of tracks *flagged* -- an infinite measurement anywhere
in the track's row of z (padding included), or a non-finite state written inside its length.  A
track's flag is a float accumulating ``(out_scale * x) * 0.0`` over the states it stores: 0.0 when
all are finite as stored.  ``out_scale`` (:data:`OUT_SCALE`) is 1 for float64 storage and 2**897 for
float32, which takes every state that float32 stores as inf (|x| >= (2 - 2**-24) 2**127) beyond
float64's range, and with them the finite ones from 2**127 up: a flag is a reason to look, not a
verdict.  The time blocks sum the values they store instead (:func:`mptrack.batch._vectors.vstore2`;
float32 sums what it stored): the sum is finite while they are.  A flagged call is then checked
again by the shared checks, which raise the named error.
The model matrices are always float64, so each kernel compiles once per
storage dtype (two signatures in total), and ``cache=True`` keeps the
machine code between processes.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.kalman import OK, linear_update, predict, workspace
from ._vectors import (fma, source, stack_buffer, vadd, vbcast, vfma, vlane, vload, vmul, vsplat,
                       vstore2, vstore_axes, vstore_pairs, vsum)

__all__ = ["ss_kernel", "ss_kernel_blocks", "kf_kernel", "kf_kernel_blocks", "gain_loop", "fir_kernel",
           "matvec_kernel"]

_OPTS = dict(parallel=True, cache=True, nogil=True, boundscheck=False)
LANES = 4   # tracks advanced together by the generic kernels
#: The ``out_scale`` argument of the filters' kernels by storage dtype (see the module's docstring).
OUT_SCALE = {np.dtype(np.float64): 1.0, np.dtype(np.float32): 2.0 ** 897}


@nb.njit(cache=True, nogil=True)
def _pad(z, out, b, zo, xo, m, n, L):
    """Steps L .. T-1 of track b (columns zo.. of z, xo.. of out): out NaN.  Returns the track's flag
    for them: 0.0, or NaN when z holds an infinity there (z is refused with one anywhere)."""
    flag = 0.0
    for t in range(L, z.shape[1]):
        for c in range(m):
            if np.isinf(z[b, t, zo + c]):
                flag = np.nan
        for r in range(n):
            out[b, t, xo + r] = np.nan
    return flag


@nb.njit(cache=True, nogil=True)
def _ss_track(z, out, b, zo, xo, t0, x, L, A, Bm, F, out_scale):
    """Track b (columns zo.. of z, xo.. of out) of :func:`ss_kernel` from time index t0 with state x
    (overwritten); returns its flag for those steps."""
    n = A.shape[0]
    m = Bm.shape[1]
    xn = np.empty(n)
    flag = 0.0
    for t in range(t0, L):
        miss = False
        for c in range(m):
            if np.isnan(z[b, t, zo + c]):
                miss = True
        if miss:
            for c in range(m):          # an infinity beside a NaN is not used, but still refused
                if np.isinf(z[b, t, zo + c]):
                    flag = np.nan
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
            flag += (out_scale * x[r]) * 0.0
    return flag + _pad(z, out, b, zo, xo, m, n, L)


@nb.njit(cache=True, nogil=True)
def _lane_steps(z, out, M, V, x0, lengths, axes, i0, lanes, out_scale):
    """Tracks i0 .. i0+lanes-1 of the generic kernels: their b, first z and x columns, and, when they
    are four, their steps together from step 0: x(k) = M[k] x(k-1) + V[k] z(k) (M, V of shape
    (1 or T, n, n) and (1 or T, n, m); one matrix for every step when the first axis is 1), while all
    four rows are complete and k is below the shortest length.  Returns (bl, zo, xo, the states X
    (n, LANES), the flags, the step where they stopped).  The states sit side by side so the four
    recursions hide each other's latency."""
    n = M.shape[1]
    m = V.shape[2]
    bl = np.empty(LANES, np.int64)
    zo = np.empty(LANES, np.int64)
    xo = np.empty(LANES, np.int64)
    X = np.empty((n, LANES))
    fl = np.zeros(LANES)
    Lmin = lengths[i0 // axes] if lanes == LANES else 0
    for lane in range(lanes):
        b = (i0 + lane) // axes
        bl[lane] = b
        zo[lane] = (i0 + lane - b * axes) * m
        xo[lane] = (i0 + lane - b * axes) * n
        Lmin = min(Lmin, lengths[b])
        for r in range(n):
            X[r, lane] = x0[b, xo[lane] + r]
    XN = np.empty((n, LANES))
    Z = np.empty((m, LANES))
    t = 0
    while t < Lmin:
        miss = False
        for c in range(m):
            for lane in range(LANES):
                v = z[bl[lane], t, zo[lane] + c]
                Z[c, lane] = v
                if np.isnan(v):
                    miss = True
        if miss:
            break
        k = t if M.shape[0] > 1 else 0
        for r in range(n):
            for lane in range(LANES):
                s = 0.0
                for c in range(n):
                    s += M[k, r, c] * X[c, lane]
                u = 0.0
                for c in range(m):
                    u += V[k, r, c] * Z[c, lane]
                XN[r, lane] = s + u
        for r in range(n):
            for lane in range(LANES):
                v = XN[r, lane]
                X[r, lane] = v
                out[bl[lane], t, xo[lane] + r] = v
                fl[lane] += (out_scale * v) * 0.0
        t += 1
    return bl, zo, xo, X, fl, t


@nb.njit(**_OPTS)
def ss_kernel(z, out, A, Bm, F, x0, lengths, axes, out_scale):
    """x(k/k) = A x(k-1/k-1) + B z(k) (Assimakis & Adam 2014, eq. 9); a row with NaN predicts, x = F x.
    Returns the number of flagged tracks.

    Any (n, m), sizes known at run time.  Four tracks advance together while
    their rows are complete (:func:`_lane_steps`); at a NaN or the shortest track's end each finishes
    on its own (:func:`_ss_track`)."""
    nb_ = z.shape[0]
    n = A.shape[0]
    m = Bm.shape[1]
    ntr = nb_ * axes
    flagged = 0
    for g in nb.prange((ntr + LANES - 1) // LANES):
        i0 = g * LANES
        lanes = min(LANES, ntr - i0)
        bl, zo, xo, X, fl, t = _lane_steps(z, out, A.reshape((1, n, n)), Bm.reshape((1, n, m)), x0, lengths,
                                           axes, i0, lanes, out_scale)
        for lane in range(lanes):
            b = bl[lane]
            if fl[lane] + _ss_track(z, out, b, zo[lane], xo[lane], t, X[:, lane].copy(), lengths[b], A, Bm, F,
                                    out_scale) != 0.0:
                flagged += 1
    return flagged


@nb.njit(cache=True, nogil=True)
def _entries(M, a):
    """The four entries of block a of M (axes, 2, 2)."""
    return M[a, 0, 0], M[a, 0, 1], M[a, 1, 0], M[a, 1, 1]


@nb.njit(cache=True, nogil=True)
def _coefficients(M, V, q):
    """The four entries of block q of M (., 2, 2) and the two of block q of V (., 2, 1): A and B of the
    steady state, A(k) and K(k) of the gain sequence."""
    return M[q, 0, 0], M[q, 0, 1], M[q, 1, 0], M[q, 1, 1], V[q, 0, 0], V[q, 1, 0]


@nb.njit(cache=True, nogil=True)
def _missing(z, b, t, a, joint):
    """Whether axis a of track b only predicts at step t: its measurement is NaN, or (``joint``: the
    axes are the blocks of one model, whose steady-state filter predicts a row with any NaN) any
    axis's is."""
    if not joint:
        return np.isnan(z[b, t, a])
    miss = False
    for c in range(z.shape[2]):
        if np.isnan(z[b, t, c]):
            miss = True
    return miss


@nb.njit(cache=True, nogil=True)
def _ss21_steps(z, out, b, a, t0, t1, p, v, A, Bm, F, out_scale, joint):
    """Steps t0 .. t1-1 of axis a of row b (its blocks A[a], Bm[a], F[a], or the 0th when there is one)
    of the steady-state filter, one at a time, from state (p, v); returns the state after them and
    their flag.  ``joint``: a row with a NaN in any axis only predicts."""
    q = a if A.shape[0] > 1 else 0      # the axis's blocks (one for all axes: q = 0)
    a00, a01, a10, a11, b0, b1 = _coefficients(A, Bm, q)
    f00, f01, f10, f11 = _entries(F, q)
    o = 2 * a
    flag = 0.0
    for t in range(t0, t1):
        zz = z[b, t, a]
        if _missing(z, b, t, a, joint):
            if np.isinf(zz):            # beside a NaN of another axis: not used, but still refused
                flag = np.nan
            p, v = f00 * p + f01 * v, f10 * p + f11 * v
        else:
            p, v = (a00 * p + a01 * v) + b0 * zz, (a10 * p + a11 * v) + b1 * zz
        out[b, t, o] = p
        out[b, t, o + 1] = v
        flag += (out_scale * p + out_scale * v) * 0.0
    return p, v, flag


@nb.njit(cache=True, nogil=True)
def own_step(F, H, Q, R, x, P, zb, t, ws, hx, periods):
    """One Kalman step (Assimakis & Adam 2014, eq. 4) with this track's own covariance P, in place: the
    predict and update of :mod:`mptrack._core.kalman` with row t of zb (this track's (T, m) columns),
    ws, hx (m,), periods (m,) of zeros: its work arrays.  NaN components are skipped; a fully missing
    row only predicts; an innovation covariance without a Cholesky factor makes x, P NaN."""
    predict(F, Q, x, P, ws)
    status, _ = linear_update(x, P, H, R, zb, t, periods, False, ws, hx)
    if status != OK:
        x[:] = np.nan
        P[:, :] = np.nan


@nb.njit(cache=True, nogil=True)
def gain_loop(F, H, Q, R, P, Ks, Pp, Pf):
    """The shared gain sequence from P = P(0/0) through the core's predict and update (the same
    arithmetic as a track's own covariance in :func:`own_step`): K(k), P(k/k-1), P(k/k) for k = 1 ..
    len(Ks).  From a step whose innovation covariance has no Cholesky factor (an overflow) on, NaN."""
    n, m = F.shape[0], H.shape[0]
    ws = workspace(n, m)
    gain = ws[1][3]
    x = np.zeros(n)          # a zero state and measurement: the update changes only P
    z = np.zeros((1, m))
    hx = np.empty(m)
    periods = np.zeros(m)
    for k in range(Ks.shape[0]):
        predict(F, Q, x, P, ws)
        Pp[k] = P
        status, _ = linear_update(x, P, H, R, z, 0, periods, False, ws, hx)
        if status != OK:
            Ks[k:] = np.nan
            Pp[k:] = np.nan
            Pf[k:] = np.nan
            return
        Ks[k] = gain
        Pf[k] = P


@nb.njit(cache=True, nogil=True)
def _kf_track(z, out, b, zo, xo, t0, x, L, F, H, Q, R, AK, K, Pf, P0, out_scale):
    """Track b (columns zo.. of z, xo.. of out) of :func:`kf_kernel` from time index t0, still on the
    shared gains, with state x (overwritten); returns its flag for those steps."""
    n = F.shape[0]
    m = H.shape[0]
    xn = np.empty(n)
    P = np.empty((n, n))
    zb = z[b, :, zo:zo + m]
    ws = workspace(n, m)
    hx = np.empty(m)
    periods = np.zeros(m)
    shared = True
    flag = 0.0
    for t in range(t0, L):
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
                    s += AK[t, r, c] * x[c]
                u = 0.0
                for c in range(m):
                    u += K[t, r, c] * z[b, t, zo + c]
                xn[r] = s + u
            for r in range(n):
                x[r] = xn[r]
        else:
            own_step(F, H, Q, R, x, P, zb, t, ws, hx, periods)
        for r in range(n):
            out[b, t, xo + r] = x[r]
            flag += (out_scale * x[r]) * 0.0
    return flag + _pad(z, out, b, zo, xo, m, n, L)


@nb.njit(**_OPTS)
def kf_kernel(z, out, F, H, Q, R, AK, K, Pf, P0, x0, lengths, axes, out_scale):
    """Kalman filter with the shared gain sequence K[t] (Assimakis & Adam 2014, eq. 4); returns the
    number of flagged tracks.

    While a track's measurements are complete it uses the precomputed gains:
    x(k/k) = A(k) x(k-1/k-1) + K(k) z(k) with A(k) = [I - K(k) H] F (:attr:`GainSequence.A`), which is
    x(k/k-1) + K(k) [z(k) - H x(k/k-1)] with a shorter chain of dependent operations; four tracks
    advance together while their rows are complete (:func:`_lane_steps`).  At its first missing
    component a track leaves the shared sequence: it takes P(k-1/k-1) = Pf[k-1] (or P0) and runs its
    own Riccati recursion from there (:func:`_kf_track`).
    """
    nb_ = z.shape[0]
    ntr = nb_ * axes
    flagged = 0
    for g in nb.prange((ntr + LANES - 1) // LANES):
        i0 = g * LANES
        lanes = min(LANES, ntr - i0)
        bl, zo, xo, X, fl, t = _lane_steps(z, out, AK, K, x0, lengths, axes, i0, lanes, out_scale)
        for lane in range(lanes):
            b = bl[lane]
            if fl[lane] + _kf_track(z, out, b, zo[lane], xo[lane], t, X[:, lane].copy(), lengths[b], F, H, Q, R,
                                    AK, K, Pf, P0, out_scale) != 0.0:
                flagged += 1
    return flagged


@nb.njit(cache=True, nogil=True)
def _kf21_track(z, out, b, a, t0, p, v, L, F, H, Q, R, AK, K, Pf, P0, out_scale):
    """Axis a of row b (its blocks of the model and gains, or the 0th when there is one) of the
    shared-gain Kalman filter from time index t0 with state (p, v), one step at a time, leaving the
    shared gains at its first gap (:func:`own_step`); returns its flag for those steps."""
    q = a if F.shape[0] > 1 else 0      # the axis's blocks (one for all axes: q = 0)
    o = 2 * a
    flag = 0.0
    t1 = L
    for t in range(t0, L):
        zz = z[b, t, a]
        if np.isnan(zz):
            t1 = t
            break
        a00, a01, a10, a11, k0, k1 = _coefficients(AK[t], K[t], q)
        p, v = (a00 * p + a01 * v) + k0 * zz, (a10 * p + a11 * v) + k1 * zz
        out[b, t, o] = p
        out[b, t, o + 1] = v
        flag += (out_scale * p + out_scale * v) * 0.0
    if t1 < L:                          # first gap: leave the shared gains
        x = np.empty(2)
        x[0] = p
        x[1] = v
        P = P0[q].copy() if t1 == 0 else Pf[t1 - 1, q].copy()
        zb = z[b, :, a:a + 1]
        ws = workspace(2, 1)
        hx = np.empty(1)
        periods = np.zeros(1)
        for t in range(t1, L):
            own_step(F[q], H[q], Q[q], R[q], x, P, zb, t, ws, hx, periods)
            out[b, t, o] = x[0]
            out[b, t, o + 1] = x[1]
            flag += (out_scale * x[0] + out_scale * x[1]) * 0.0
    return flag + _pad(z, out, b, a, o, 1, 2, L)


@nb.njit(cache=True, nogil=True)
def _coefficients8(C, c0):
    """The coefficients C[c0 .. c0+159] of one time block (:func:`mptrack.batch._filters.time_blocks`) as
    vectors: per row (the weights of z_j, j = 0..7, then of the two state components) its first and
    last eight entries, and the four weights of the state in the block's last state.  Loaded before a
    loop of blocks, they stay in registers: loaded inside it, every store to ``out`` (which LLVM cannot
    tell apart from C) makes them be loaded again."""
    return ((vload(C, c0), vload(C, c0 + 8), vload(C, c0 + 16), vload(C, c0 + 24), vload(C, c0 + 32),
             vload(C, c0 + 40), vload(C, c0 + 48), vload(C, c0 + 56), vload(C, c0 + 72), vload(C, c0 + 88),
             vload(C, c0 + 104), vload(C, c0 + 120), vload(C, c0 + 128), vload(C, c0 + 136), vload(C, c0 + 144),
             vload(C, c0 + 152)),
            (C[c0 + 142], C[c0 + 158], C[c0 + 143], C[c0 + 159]))


@nb.njit(cache=True, nogil=True)
def _block(zf, zi, zs, p, v, W, g):
    """Eight steps of one n = 2, m = 1 axis as vectors (see :func:`ss_kernel_blocks`): from the state
    (p, v) before them and the measurements zf[zi + j zs], j = 0..7, with the block's coefficients
    (W, g) = :func:`_coefficients8`; returns the last state and the sixteen states (position, velocity
    of each step) as two vectors."""
    z0, z1, z2, z3 = vbcast(zf, zi), vbcast(zf, zi + zs), vbcast(zf, zi + 2 * zs), vbcast(zf, zi + 3 * zs)
    z4, z5 = vbcast(zf, zi + 4 * zs), vbcast(zf, zi + 5 * zs)
    z6, z7 = vbcast(zf, zi + 6 * zs), vbcast(zf, zi + 7 * zs)
    # the first four steps do not depend on z4 .. z7 (their weights are zero)
    lo = vadd(vfma(z1, W[2], vmul(z0, W[0])), vfma(z3, W[6], vmul(z2, W[4])))
    hi = vadd(vfma(z3, W[7], vfma(z2, W[5], vfma(z1, W[3], vmul(z0, W[1])))),
              vfma(z7, W[11], vfma(z6, W[10], vfma(z5, W[9], vmul(z4, W[8])))))
    # the state's part last: the chain from one block's state to the next is two multiply-adds (the
    # same fused operations as the vector lane's, so bitwise its value)
    pn = fma(v, g[1], fma(p, g[0], vlane(hi, 6)))
    vn = fma(v, g[3], fma(p, g[2], vlane(hi, 7)))
    ps, vs = vsplat(p), vsplat(v)
    return pn, vn, vfma(vs, W[14], vfma(ps, W[12], lo)), vfma(vs, W[15], vfma(ps, W[13], hi))


@nb.njit(cache=True, nogil=True)
def _axis_blocks(zf, zi, zs, of, oi, os, n, p, v, W, g, acc):
    """n blocks of one axis (:func:`_block`) from zf[zi] (a step every zs values) into of[oi] (a step
    every os values: 2 when the row is this axis alone, stored as whole vectors, else as pairs);
    returns the state after them and ``acc`` plus the sum of the values stored, which stays finite
    while they are (:func:`mptrack.batch._vectors.vstore2`)."""
    for i in range(n):
        p, v, lo, hi = _block(zf, zi + 8 * zs * i, zs, p, v, W, g)
        if os == 2:
            acc = vadd(acc, vstore2(of, oi + 16 * i, lo, hi))
        else:
            acc = vadd(acc, vstore_pairs(of, oi + 8 * os * i, os, lo, hi))
    return p, v, acc


@nb.njit(cache=True, nogil=True)
def _rows2(src, s0, of, o0, n, P, V, W, g, acc):
    """:func:`_rows` of two axes with the same coefficients (W, g) for the n blocks: both axes' block
    i, then its 32 values stored as whole vectors, interleaved as the rows hold them
    (:func:`mptrack.batch._vectors.vstore_axes`)."""
    p0, v0, p1, v1 = P[0], V[0], P[1], V[1]
    for i in range(n):
        p0, v0, lo0, hi0 = _block(src, s0 + 16 * i, 2, p0, v0, W, g)
        p1, v1, lo1, hi1 = _block(src, s0 + 16 * i + 1, 2, p1, v1, W, g)
        acc = vadd(acc, vstore_axes(of, o0 + 32 * i, (lo0, hi0, lo1, hi1)))
    P[0], V[0], P[1], V[1] = p0, v0, p1, v1
    return acc


@nb.njit(cache=True, nogil=True)
def _rows3(src, s0, of, o0, n, P, V, C, c, acc):
    """:func:`_rows2` for three axes, with the coefficients loaded in each block: kept in registers
    beside three axes' vectors they made LLVM spill some thirty vectors a block (0.70 against 0.54-0.59
    ns per axis-update in cache); for two axes keeping them is the faster (0.57-0.70 against 0.69-0.79,
    alternating runs)."""
    p0, v0, p1, v1, p2, v2 = P[0], V[0], P[1], V[1], P[2], V[2]
    for i in range(n):
        W, g = _coefficients8(C[0, c], 0)
        p0, v0, lo0, hi0 = _block(src, s0 + 24 * i, 3, p0, v0, W, g)
        p1, v1, lo1, hi1 = _block(src, s0 + 24 * i + 1, 3, p1, v1, W, g)
        p2, v2, lo2, hi2 = _block(src, s0 + 24 * i + 2, 3, p2, v2, W, g)
        acc = vadd(acc, vstore_axes(of, o0 + 48 * i, (lo0, hi0, lo1, hi1, lo2, hi2)))
    P[0], V[0], P[1], V[1], P[2], V[2] = p0, v0, p1, v1, p2, v2
    return acc


@nb.njit(cache=True, nogil=True)
def _rows(src, s0, k, of, o0, n, P, V, C, c, step, acc):
    """n blocks of rows of k axes (states P, V, updated) from src[s0] into of[o0], one axis after the
    other (:func:`_axis_blocks`), axis a's block i with the coefficients C[a, c + step i] (C[0, ..] for
    all when C has one axis block): step 0 keeps them in registers for the n blocks.  Two or three
    axes with the same coefficients for the n blocks run block by block instead, their values stored
    as whole vectors (:func:`_rows2`, :func:`_rows3`; pairs cost 0.70 ns per axis-update in cache,
    whole vectors 0.54-0.59).  Returns ``acc`` plus the sum of the values stored."""
    if step == 0 and C.shape[0] == 1 and k == 2:      # the same axis twice (model A 2-D, per_axis)
        W, g = _coefficients8(C[0, c], 0)
        return _rows2(src, s0, of, o0, n, P, V, W, g, acc)
    if step == 0 and C.shape[0] == 1 and k == 3:
        return _rows3(src, s0, of, o0, n, P, V, C, c, acc)
    for a in range(k):
        ca = a if C.shape[0] > 1 else 0
        if step == 0:
            W, g = _coefficients8(C[ca, c], 0)
            P[a], V[a], acc = _axis_blocks(src, s0 + a, k, of, o0 + 2 * a, 2 * k, n, P[a], V[a], W, g, acc)
        else:
            for i in range(n):
                W, g = _coefficients8(C[ca, c + step * i], 0)
                P[a], V[a], acc = _axis_blocks(src, s0 + a + 8 * k * i, k, of, o0 + 2 * a + 16 * k * i, 2 * k, 1,
                                               P[a], V[a], W, g, acc)
    return acc


#: Axes per row the block kernels take (their states live on the stack); more run the generic kernels.
MAX_AXES = 8
#: Measurements per chunk: a chunk's rows are checked (float32: widened to float64, one conversion per
#: eight values) before their blocks run; 2048 steps of one axis, 256 of eight (16 KiB of stack).
_WIDE = 2048


@nb.njit(cache=True, nogil=True)
def _priors(x0, b, k, P, V):
    """The prior states of row b's k axes (position, velocity) into P, V."""
    for a in range(k):
        P[a] = x0[b, 2 * a]
        V[a] = x0[b, 2 * a + 1]


@nb.njit(**_OPTS)
def ss_kernel_blocks(z, out, zf, of, A, Bm, F, C, x0, lengths, out_scale, joint):
    """x(k/k) = A x(k-1/k-1) + B z(k) (Assimakis & Adam 2014, eq. 9) for rows of k axes of n = 2, m = 1
    (model B on z (B, T, 1); per axis; the axes of a block-diagonal model, ``joint``: its rule that a
    row with a NaN in any axis only predicts), eight steps at a time as vectors: x(k+s) = A^(s+1) x(k-1)
    + sum_{j <= s} A^(s-j) B z(k+j), s = 0..7 (the FIR form of eq. 22 over one block, exact), in
    sixteen lanes that lie as the states of one axis lie in ``out`` (position, velocity of each step):
    measurements are read as broadcasts, the states stored as whole vectors (one axis per row) or as
    pairs into the rows, and one block's state reaches the next through two multiply-adds.
    zf, of: z and out as 1-D arrays; A, Bm, F (q, ., .) and C (q, 1, 160): axis a's blocks and time-block
    coefficients (:func:`mptrack.batch._filters.time_blocks`) are those of a (q = k) or of 0 (q = 1).
    The rows are taken in chunks (:data:`_WIDE` values); blocks before the first with a NaN or an infinity run
    as vectors, that one step by step (:func:`_ss21_steps`, which also refuses an infinity beside a
    NaN), as do the last L mod 8 steps.  Returns the number of flagged rows."""
    nb_, T, k = z.shape[0], z.shape[1], z.shape[2]
    flagged = 0
    for b in nb.prange(nb_):
        L = lengths[b]
        # scratch on the stack of the kernel itself (a helper's stack is gone when it returns)
        P, V = nb.carray(stack_buffer(MAX_AXES), MAX_AXES), nb.carray(stack_buffer(MAX_AXES), MAX_AXES)
        buf = nb.carray(stack_buffer(_WIDE), _WIDE)
        _priors(x0, b, k, P, V)
        acc = vsplat(0.0)
        flag = 0.0
        t = 0
        while t + 8 <= L:
            n = min((L - t) // 8, _WIDE // (8 * k))
            src, s0, done = source(zf, (b * T + t) * k, k, n, buf)
            acc = _rows(src, s0, k, of, 2 * (b * T + t) * k, done, P, V, C, 0, 0, acc)
            t += 8 * done
            if done < n:                # a block with a NaN or an infinity: its rows step by step
                for a in range(k):
                    P[a], V[a], f = _ss21_steps(z, out, b, a, t, t + 8, P[a], V[a], A, Bm, F, out_scale, joint)
                    flag += f
                t += 8
        for a in range(k):
            P[a], V[a], f = _ss21_steps(z, out, b, a, t, L, P[a], V[a], A, Bm, F, out_scale, joint)
            flag += f + _pad(z, out, b, a, 2 * a, 1, 2, L)
        if flag != 0.0 or vsum(acc) * 0.0 != 0.0:
            flagged += 1
    return flagged


@nb.njit(**_OPTS)
def kf_kernel_blocks(z, out, zf, of, F, H, Q, R, AK, K, Pf, P0, C, settled, x0, lengths, out_scale):
    """Kalman filter with the shared gain sequence (Assimakis & Adam 2014, eq. 4) for rows of k axes of
    n = 2, m = 1, eight steps at a time as vectors as in :func:`ss_kernel_blocks`, with
    x(k/k) = A(k) x(k-1/k-1) + K(k) z(k): F, H, Q, R, P0 (q, ., .), AK, K, Pf (T, q, ., .) the axes'
    blocks, C (q, N, 160) their time-block coefficients for blocks 0 .. N-1 (from A(k), K(k)), all equal
    from block ``settled`` = N - 1 on (:func:`mptrack.batch._filters.gain_blocks`): from there they are
    loaded once per chunk, before it per block.  A block of rows with a NaN or an infinity hands every
    axis over to :func:`_kf21_track` (which leaves the shared gains at the axis's first gap), as do
    the last L mod 8 steps.  Returns the number of flagged rows."""
    nb_, T, k = z.shape[0], z.shape[1], z.shape[2]
    flagged = 0
    for b in nb.prange(nb_):
        L = lengths[b]
        # scratch on the stack of the kernel itself (a helper's stack is gone when it returns)
        P, V = nb.carray(stack_buffer(MAX_AXES), MAX_AXES), nb.carray(stack_buffer(MAX_AXES), MAX_AXES)
        buf = nb.carray(stack_buffer(_WIDE), _WIDE)
        _priors(x0, b, k, P, V)
        acc = vsplat(0.0)
        t = 0
        n = done = 0
        while done == n and t + 8 <= L:
            i = t // 8                  # the blocks before ``settled`` each with its coefficients
            n = min((L - t) // 8, _WIDE // (8 * k), settled - i if i < settled else L)
            src, s0, done = source(zf, (b * T + t) * k, k, n, buf)
            acc = _rows(src, s0, k, of, 2 * (b * T + t) * k, done, P, V, C, min(i, settled), int(i < settled),
                        acc)
            t += 8 * done
        flag = 0.0
        for a in range(k):
            if t < L:
                flag += _kf21_track(z, out, b, a, t, P[a], V[a], L, F, H, Q, R, AK, K, Pf, P0, out_scale)
            else:                       # (calling it for no step cost 100 ns a track)
                flag += _pad(z, out, b, a, 2 * a, 1, 2, L)
        if flag != 0.0 or vsum(acc) * 0.0 != 0.0:
            flagged += 1
    return flagged


@nb.njit(**_OPTS)
def fir_kernel(z, out, C, lengths, axes, bad):
    """x(k/k) = sum_{j < min(M, k)} C_j z(k-j), C_j = A^j B (Assimakis & Adam 2014, eq. 22,
    truncated warm-up).

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
        y = np.empty(n)                 # out may be x itself: read the state before writing
        for t in range(T):
            for r in range(n):
                s = 0.0
                for c in range(n):
                    s += M[r, c] * x[b, t, o + c]
                y[r] = s
            for r in range(n):
                out[b, t, o + r] = y[r]
