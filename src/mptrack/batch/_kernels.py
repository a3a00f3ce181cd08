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
the plain joint model.  The n = 2, m = 1 lane kernels also run the axes of a block-diagonal joint
model (model A) this way, each with its own blocks of the model's matrices.

A track with its own covariance (the KF after its first gap) runs the one compiled
predict/update of :mod:`mptrack._kalman_core` (:func:`own_step`).  The shared-gain paths are the
documented exception: four tracks advance together with the shared gains, x = A(k) x + K(k) z --
in registers in the n = 2, m = 1 lane kernels (``ss_kernel_21``, ``kf_kernel_21``), side by side in
small arrays in the generic ones (:func:`_lane_steps`); tests/test_kalman_core.py checks them
against the core.  One n = 2, m = 1 track per row (model B on z (B, T, 1)) runs in *time blocks*
instead: eight steps at a time as vectors (``ss_kernel_blocks``, ``kf_kernel_blocks``, docs/design.md
"Time blocks"), with the scalar steps above for blocks with a gap and for a track's last steps.

The state is carried in float64 whatever the storage dtype; float32 only
halves the bytes streamed.  Steps ``t >= lengths[b]`` are written as NaN.

The filters' kernels also do the finiteness checks of their data while they stream it (a separate
pass over z and one over the output cost as much as the filter, docs/design.md "Checks fused into
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

from .. import _jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._kalman_core import OK, linear_update, predict, workspace
from ._vectors import fma, narrow, stack_buffer, vadd, vbcast, vfma, vlane, vload, vmul, vsplat, vstore, vstore2, vsum

__all__ = ["ss_kernel", "ss_kernel_21", "ss_kernel_blocks", "kf_kernel", "kf_kernel_21", "kf_kernel_blocks",
           "gain_loop", "fir_kernel", "matvec_kernel"]

_OPTS = dict(parallel=True, cache=True, nogil=True, boundscheck=False)
LANES = 4   # tracks advanced together by the n = 2, m = 1 kernels
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

    Any (n, m), sizes known at run time.  As in the lane kernels, four tracks advance together while
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
def _lanes(i0, axes, lengths):
    """Tracks i0 .. i0+3 of a group as (b, axis) pairs, and the shortest of their lengths."""
    b1, b2, b3, b4 = i0 // axes, (i0 + 1) // axes, (i0 + 2) // axes, (i0 + 3) // axes
    c1, c2, c3, c4 = i0 - b1 * axes, i0 + 1 - b2 * axes, i0 + 2 - b3 * axes, i0 + 3 - b4 * axes
    Lmin = min(min(lengths[b1], lengths[b2]), min(lengths[b3], lengths[b4]))
    return b1, b2, b3, b4, c1, c2, c3, c4, Lmin


@nb.njit(cache=True, nogil=True)
def _lane_priors(x0, b1, b2, b3, b4, c1, c2, c3, c4):
    """The priors (position, velocity) of the four lanes."""
    return (x0[b1, 2 * c1], x0[b1, 2 * c1 + 1], x0[b2, 2 * c2], x0[b2, 2 * c2 + 1],
            x0[b3, 2 * c3], x0[b3, 2 * c3 + 1], x0[b4, 2 * c4], x0[b4, 2 * c4 + 1])


@nb.njit(cache=True, nogil=True)
def _entries(M, a):
    """The four entries of block a of M (axes, 2, 2)."""
    return M[a, 0, 0], M[a, 0, 1], M[a, 1, 0], M[a, 1, 1]


@nb.njit(cache=True, nogil=True)
def _coefficients(M, V, q):
    """The four entries of block q of M (., 2, 2) and the two of block q of V: Bm (., 2, 1) or H (., 1, 2)."""
    second = V[q, 1, 0] if V.shape[2] == 1 else V[q, 0, 1]
    return M[q, 0, 0], M[q, 0, 1], M[q, 1, 0], M[q, 1, 1], V[q, 0, 0], second


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
    """Steps t0 .. t1-1 of track (b, axis a) of :func:`ss_kernel_21` from state (p, v); returns the
    state after them and their flag."""
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
def _ss21_track(z, out, b, a, t0, p, v, L, A, Bm, F, out_scale, joint):
    """Track (b, axis a) of :func:`ss_kernel_21` from time index t0 with state (p, v); returns its flag
    for those steps."""
    p, v, flag = _ss21_steps(z, out, b, a, t0, L, p, v, A, Bm, F, out_scale, joint)
    return flag + _pad(z, out, b, a, 2 * a, 1, 2, L)


@nb.njit(**_OPTS)
def ss_kernel_21(z, out, A, Bm, F, x0, lengths, axes, out_scale, joint):
    """:func:`ss_kernel` written out for axes of n = 2, m = 1; returns the number of flagged tracks.

    A (q, 2, 2), Bm (q, 2, 1), F (q, 2, 2): axis a of a row is the track (b, a) with the matrices
    A[a], Bm[a], F[a] (q = axes), or A[0], Bm[0], F[0] for every axis (q = 1) -- model B per axis, or
    the diagonal blocks of a block-diagonal model (``joint``: then a row with a NaN in any axis only
    predicts, as :func:`ss_kernel` does).
    Four tracks advance together (``LANES``): their states and coefficients live in registers and
    their four independent recursions hide the floating-point latency, so the loop runs at memory
    speed.  When a lane meets a NaN, or the shortest of the four tracks ends, each lane finishes on
    its own (:func:`_ss21_track`).
    """
    nb_ = z.shape[0]
    ntr = nb_ * axes
    ngroups = (ntr + LANES - 1) // LANES
    rows = joint and LANES % axes != 0   # else a group holds whole tracks: a NaN in any lane stops it
    # (axes 1, 2 or 4); rows: axes >= 3, so a group's four lanes span two tracks at most
    flagged = 0
    for g in nb.prange(ngroups):
        i0 = g * LANES
        if i0 + LANES > ntr:            # the last, incomplete group: one track at a time
            for i in range(i0, ntr):
                b = i // axes
                a = i - b * axes
                if _ss21_track(z, out, b, a, 0, x0[b, 2 * a], x0[b, 2 * a + 1], lengths[b], A, Bm, F,
                               out_scale, joint) != 0.0:
                    flagged += 1
            continue
        b1_, b2_, b3_, b4_, c1, c2, c3, c4, Lmin = _lanes(i0, axes, lengths)
        q = 0 if A.shape[0] == 1 else 1     # one block for every lane, or each lane's axis's
        flagged += _ss21_group(z, out, x0, A, Bm, F, lengths, out_scale, joint, rows, b1_, b2_, b3_, b4_,
                               c1, c2, c3, c4, Lmin, q * c1, q * c2, q * c3, q * c4)
    return flagged


@nb.njit(cache=True, nogil=True)
def _store_lanes(out, t, b1_, b2_, b3_, b4_, c1, c2, c3, c4, p1, v1, p2, v2, p3, v3, p4, v4, out_scale):
    """Write the four lanes' states at step t; returns the terms of their flags."""
    out[b1_, t, 2 * c1], out[b1_, t, 2 * c1 + 1] = p1, v1
    out[b2_, t, 2 * c2], out[b2_, t, 2 * c2 + 1] = p2, v2
    out[b3_, t, 2 * c3], out[b3_, t, 2 * c3 + 1] = p3, v3
    out[b4_, t, 2 * c4], out[b4_, t, 2 * c4 + 1] = p4, v4
    return ((out_scale * p1 + out_scale * v1) * 0.0, (out_scale * p2 + out_scale * v2) * 0.0,
            (out_scale * p3 + out_scale * v3) * 0.0, (out_scale * p4 + out_scale * v4) * 0.0)


@nb.njit(cache=True, nogil=True)
def _ss21_group(z, out, x0, A, Bm, F, lengths, out_scale, joint, rows, b1_, b2_, b3_, b4_, c1, c2, c3, c4, Lmin,
                q1, q2, q3, q4):
    """One group of :func:`ss_kernel_21`: lanes (b1_, c1) .. (b4_, c4) with the blocks q1 .. q4 of
    A, Bm, F; returns how many of them are flagged."""
    p1, v1, p2, v2, p3, v3, p4, v4 = _lane_priors(x0, b1_, b2_, b3_, b4_, c1, c2, c3, c4)
    a1, e1, h1, k1, u1, w1 = _coefficients(A, Bm, q1)
    a2, e2, h2, k2, u2, w2 = _coefficients(A, Bm, q2)
    a3, e3, h3, k3, u3, w3 = _coefficients(A, Bm, q3)
    a4, e4, h4, k4, u4, w4 = _coefficients(A, Bm, q4)
    f1 = f2 = f3 = f4 = 0.0
    t = 0
    while t < Lmin:
        if rows:                        # whole rows (axes >= 3: the four lanes span two tracks at most)
            if _missing(z, b1_, t, c1, True) or _missing(z, b4_, t, c4, True):
                break
        elif (np.isnan(z[b1_, t, c1]) or np.isnan(z[b2_, t, c2]) or np.isnan(z[b3_, t, c3])
                or np.isnan(z[b4_, t, c4])):
            break
        z1, z2, z3, z4 = z[b1_, t, c1], z[b2_, t, c2], z[b3_, t, c3], z[b4_, t, c4]
        p1, v1 = (a1 * p1 + e1 * v1) + u1 * z1, (h1 * p1 + k1 * v1) + w1 * z1
        p2, v2 = (a2 * p2 + e2 * v2) + u2 * z2, (h2 * p2 + k2 * v2) + w2 * z2
        p3, v3 = (a3 * p3 + e3 * v3) + u3 * z3, (h3 * p3 + k3 * v3) + w3 * z3
        p4, v4 = (a4 * p4 + e4 * v4) + u4 * z4, (h4 * p4 + k4 * v4) + w4 * z4
        r1, r2, r3, r4 = _store_lanes(out, t, b1_, b2_, b3_, b4_, c1, c2, c3, c4, p1, v1, p2, v2, p3, v3, p4, v4,
                                      out_scale)
        f1, f2, f3, f4 = f1 + r1, f2 + r2, f3 + r3, f4 + r4
        t += 1
    f1 += _ss21_track(z, out, b1_, c1, t, p1, v1, lengths[b1_], A, Bm, F, out_scale, joint)
    f2 += _ss21_track(z, out, b2_, c2, t, p2, v2, lengths[b2_], A, Bm, F, out_scale, joint)
    f3 += _ss21_track(z, out, b3_, c3, t, p3, v3, lengths[b3_], A, Bm, F, out_scale, joint)
    f4 += _ss21_track(z, out, b4_, c4, t, p4, v4, lengths[b4_], A, Bm, F, out_scale, joint)
    return _count_flags(f1, f2, f3, f4)


@nb.njit(cache=True, nogil=True)
def _count_flags(f1, f2, f3, f4):
    """How many of four lanes' flags are set (not 0.0)."""
    return int(f1 != 0.0) + int(f2 != 0.0) + int(f3 != 0.0) + int(f4 != 0.0)


@nb.njit(cache=True, nogil=True)
def own_step(F, H, Q, R, x, P, zb, t, ws, hx, periods):
    """One Kalman step (Assimakis & Adam 2014, eq. 4) with this track's own covariance P, in place: the
    predict and update of :mod:`mptrack._kalman_core` with row t of zb (this track's (T, m) columns),
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
    """Track (b, axis a) of :func:`kf_kernel_21` from time index t0 with state (p, v); returns its flag
    for those steps."""
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


@nb.njit(**_OPTS)
def kf_kernel_21(z, out, F, H, Q, R, AK, K, Pf, P0, x0, lengths, axes, out_scale):
    """:func:`kf_kernel` written out for axes of n = 2, m = 1, four tracks at a time (see
    :func:`ss_kernel_21`); returns the number of flagged tracks.

    F, H, Q, R, P0 (q, ., .), and the shared sequences AK, K, Pf (T, q, ., .): the blocks of axis a (of
    axis 0 when q = 1) are the track (b, a)'s model and gains.  While a track's measurements are
    complete it runs x(k/k) = A(k) x(k-1/k-1) + K(k) z(k) with A(k) = [I - K(k) H] F
    (:attr:`mptrack.batch.GainSequence.A`), the same filter as x(k/k-1) + K(k) [z(k) - H x(k/k-1)]
    with a chain of two dependent multiply-adds per step instead of five (four lanes did not hide the
    longer one); at its first gap it leaves the shared gains for its own covariance (:func:`own_step`).
    A joint block-diagonal model needs no joint rule here: its covariance stays block diagonal, so a
    NaN in one axis leaves the others' updates as they are."""
    nb_ = z.shape[0]
    ntr = nb_ * axes
    ngroups = (ntr + LANES - 1) // LANES
    flagged = 0
    for g in nb.prange(ngroups):
        i0 = g * LANES
        if i0 + LANES > ntr:
            for i in range(i0, ntr):
                b = i // axes
                a = i - b * axes
                if _kf21_track(z, out, b, a, 0, x0[b, 2 * a], x0[b, 2 * a + 1], lengths[b],
                               F, H, Q, R, AK, K, Pf, P0, out_scale) != 0.0:
                    flagged += 1
            continue
        b1_, b2_, b3_, b4_, c1, c2, c3, c4, Lmin = _lanes(i0, axes, lengths)
        q = 0 if F.shape[0] == 1 else 1     # one block (and gain) for every lane, or each lane's axis's
        flagged += _kf21_group(z, out, x0, F, H, Q, R, AK, K, Pf, P0, lengths, out_scale, b1_, b2_, b3_, b4_,
                               c1, c2, c3, c4, Lmin, q * c1, q * c2, q * c3, q * c4)
    return flagged


@nb.njit(cache=True, nogil=True)
def _kf21_group(z, out, x0, F, H, Q, R, AK, K, Pf, P0, lengths, out_scale, b1_, b2_, b3_, b4_, c1, c2, c3, c4, Lmin,
                q1, q2, q3, q4):
    """One group of :func:`kf_kernel_21`: lanes (b1_, c1) .. (b4_, c4) with the blocks q1 .. q4 of the
    model and gains; returns how many of them are flagged."""
    p1, v1, p2, v2, p3, v3, p4, v4 = _lane_priors(x0, b1_, b2_, b3_, b4_, c1, c2, c3, c4)
    g1 = g2 = g3 = g4 = 0.0
    t = 0
    while t < Lmin:
        z1, z2, z3, z4 = z[b1_, t, c1], z[b2_, t, c2], z[b3_, t, c3], z[b4_, t, c4]
        if np.isnan(z1) or np.isnan(z2) or np.isnan(z3) or np.isnan(z4):
            break
        At, Kt = AK[t], K[t]
        a1, e1, h1, k1, u1, w1 = _coefficients(At, Kt, q1)
        a2, e2, h2, k2, u2, w2 = _coefficients(At, Kt, q2)
        a3, e3, h3, k3, u3, w3 = _coefficients(At, Kt, q3)
        a4, e4, h4, k4, u4, w4 = _coefficients(At, Kt, q4)
        p1, v1 = (a1 * p1 + e1 * v1) + u1 * z1, (h1 * p1 + k1 * v1) + w1 * z1
        p2, v2 = (a2 * p2 + e2 * v2) + u2 * z2, (h2 * p2 + k2 * v2) + w2 * z2
        p3, v3 = (a3 * p3 + e3 * v3) + u3 * z3, (h3 * p3 + k3 * v3) + w3 * z3
        p4, v4 = (a4 * p4 + e4 * v4) + u4 * z4, (h4 * p4 + k4 * v4) + w4 * z4
        r1, r2, r3, r4 = _store_lanes(out, t, b1_, b2_, b3_, b4_, c1, c2, c3, c4, p1, v1, p2, v2, p3, v3, p4, v4,
                                      out_scale)
        g1, g2, g3, g4 = g1 + r1, g2 + r2, g3 + r3, g4 + r4
        t += 1
    g1 += _kf21_track(z, out, b1_, c1, t, p1, v1, lengths[b1_], F, H, Q, R, AK, K, Pf, P0, out_scale)
    g2 += _kf21_track(z, out, b2_, c2, t, p2, v2, lengths[b2_], F, H, Q, R, AK, K, Pf, P0, out_scale)
    g3 += _kf21_track(z, out, b3_, c3, t, p3, v3, lengths[b3_], F, H, Q, R, AK, K, Pf, P0, out_scale)
    g4 += _kf21_track(z, out, b4_, c4, t, p4, v4, lengths[b4_], F, H, Q, R, AK, K, Pf, P0, out_scale)
    return _count_flags(g1, g2, g3, g4)


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
def _time_block(zf, zi, of, oi, p, v, W, g, acc):
    """Eight steps of an n = 2, m = 1 track as vectors (see :func:`ss_kernel_blocks`): the
    measurements zf[zi .. zi+7] and the states after them, stored in of[oi .. oi+15] (position,
    velocity of each step) from the state (p, v) before them, with the block's coefficients
    (W, g) = :func:`_coefficients8`.  Stores them and returns (p, v, acc, True) when the last state is
    finite, else stores nothing and returns False (a NaN or infinity among the eight measurements
    always reaches it: its weights multiply every one of them, zero weights included).  ``acc``
    accumulates the states stored: it stays finite while they are."""
    z0, z1, z2, z3 = vbcast(zf, zi), vbcast(zf, zi + 1), vbcast(zf, zi + 2), vbcast(zf, zi + 3)
    z4, z5, z6, z7 = vbcast(zf, zi + 4), vbcast(zf, zi + 5), vbcast(zf, zi + 6), vbcast(zf, zi + 7)
    # the first four steps do not depend on z4 .. z7 (their weights are zero)
    lo = vadd(vfma(z1, W[2], vmul(z0, W[0])), vfma(z3, W[6], vmul(z2, W[4])))
    hi = vadd(vfma(z3, W[7], vfma(z2, W[5], vfma(z1, W[3], vmul(z0, W[1])))),
              vfma(z7, W[11], vfma(z6, W[10], vfma(z5, W[9], vmul(z4, W[8])))))
    # the state's part last: the chain from one block's state to the next is two multiply-adds
    pn = fma(v, g[1], fma(p, g[0], vlane(hi, 6)))
    vn = fma(v, g[3], fma(p, g[2], vlane(hi, 7)))
    if pn * 0.0 + vn * 0.0 != 0.0:
        return p, v, acc, False
    ps, vs = vsplat(p), vsplat(v)
    lo = vfma(vs, W[14], vfma(ps, W[12], lo))
    hi = vfma(vs, W[15], vfma(ps, W[13], hi))
    return pn, vn, vadd(acc, vstore2(of, oi, lo, hi)), True


#: Steps of a float32 track widened to float64 at a time before its blocks read them (a multiple of 8).
WIDEN = 256


@nb.njit(cache=True, nogil=True)
def _blocks(zf, zi, of, oi, n, p, v, W, g, acc, buf):
    """Up to n time blocks (:func:`_time_block`) from zf[zi] and of[oi] with the coefficients (W, g)
    from the state (p, v); returns (p, v, acc, the number of blocks done), fewer than n when a block's
    last state is not finite (that block is not done).  float32 measurements are first widened to
    float64 in ``buf`` (WIDEN steps at a time, one conversion per eight values) so that the blocks read
    them as float64 broadcasts: widened one at a time as they are broadcast, they cost a float32 block a
    third more instructions."""
    if narrow(zf):
        done = 0
        while done < n:
            k = min(n - done, WIDEN // 8)
            z0 = zi + 8 * done
            for i in range(k):
                vstore(buf, 8 * i, vload(zf, z0 + 8 * i))
            for j in range(k):
                p, v, acc, ok = _time_block(buf, 8 * j, of, oi + 16 * (done + j), p, v, W, g, acc)
                if not ok:
                    return p, v, acc, done + j
            done += k
        return p, v, acc, n
    for j in range(n):
        p, v, acc, ok = _time_block(zf, zi + 8 * j, of, oi + 16 * j, p, v, W, g, acc)
        if not ok:
            return p, v, acc, j
    return p, v, acc, n


@nb.njit(**_OPTS)
def ss_kernel_blocks(z, out, zf, of, A, Bm, F, C, x0, lengths, out_scale):
    """:func:`ss_kernel_21` for one n = 2, m = 1 track per row (model B on z (B, T, 1)), eight steps
    at a time as vectors: x(k+s) = A^(s+1) x(k-1) + sum_{j <= s} A^(s-j) B z(k+j), s = 0..7 (the
    FIR form of eq. 22 of Assimakis & Adam 2014 over one block, exact), in sixteen lanes that lie as
    the states lie in ``out`` (position, velocity of each step): measurements are read as broadcasts,
    states stored as whole vectors, and one block's state reaches the next through two multiply-adds.
    zf, of: z and out as 1-D arrays; C (160,): the block's coefficients
    (:func:`mptrack.batch._filters.time_blocks`).  A block with a
    NaN (or infinity) among its measurements runs the scalar steps (:func:`_ss21_steps`), as do the
    last L mod 8 steps.  Returns the number of flagged tracks."""
    nb_, T = z.shape[0], z.shape[1]
    flagged = 0
    for b in nb.prange(nb_):
        L = lengths[b]
        p, v = x0[b, 0], x0[b, 1]
        W, g = _coefficients8(C, 0)
        buf = nb.carray(stack_buffer(WIDEN), WIDEN)
        acc = vsplat(0.0)
        flag = 0.0
        t = 0
        while t + 8 <= L:
            n = (L - t) // 8
            p, v, acc, k = _blocks(zf, b * T + t, of, 2 * (b * T + t), n, p, v, W, g, acc, buf)
            t += 8 * k
            if k < n:                   # a block with a NaN: its scalar steps
                p, v, f = _ss21_steps(z, out, b, 0, t, t + 8, p, v, A, Bm, F, out_scale, False)
                flag += f
                t += 8
        p, v, f = _ss21_steps(z, out, b, 0, t, L, p, v, A, Bm, F, out_scale, False)
        flag += f + _pad(z, out, b, 0, 0, 1, 2, L)
        if flag != 0.0 or vsum(acc) * 0.0 != 0.0:
            flagged += 1
    return flagged


@nb.njit(**_OPTS)
def kf_kernel_blocks(z, out, zf, of, F, H, Q, R, AK, K, Pf, P0, C, settled, x0, lengths, out_scale):
    """:func:`kf_kernel_21` for one n = 2, m = 1 track per row, eight steps at a time as vectors as in
    :func:`ss_kernel_blocks`, with the shared gains: block i (steps 8i .. 8i+7) has its own
    coefficients C[i] (from A(k) and K(k), :attr:`mptrack.batch.GainSequence.blocks`) up to block
    ``settled``, from which on they are all equal (the gains reach their limit exactly in floating
    point after some tens of steps) and stay in registers: loading them for every block made the
    loop twice as slow.  At a block with a NaN or infinity the track goes on in :func:`_kf21_track`
    (which leaves the shared gains at its first gap), as do its last L mod 8 steps.  Returns the
    number of flagged tracks."""
    nb_, T = z.shape[0], z.shape[1]
    stride = C.shape[1]
    Cf = C.reshape(-1)
    Cs = C[min(settled, max(C.shape[0] - 1, 0))]     # (a view only; T < 8 has no block to read it)
    flagged = 0
    for b in nb.prange(nb_):
        L = lengths[b]
        p, v = x0[b, 0], x0[b, 1]
        buf = nb.carray(stack_buffer(WIDEN), WIDEN)
        acc = vsplat(0.0)
        t = 0
        k = n = 1
        while k == n and t + 8 <= L and t < 8 * settled:
            W, g = _coefficients8(Cf, (t // 8) * stride)
            p, v, acc, k = _blocks(zf, b * T + t, of, 2 * (b * T + t), 1, p, v, W, g, acc, buf)
            t += 8 * k
        if k == n and t + 8 <= L:
            W, g = _coefficients8(Cs, 0)
            n = (L - t) // 8
            p, v, acc, k = _blocks(zf, b * T + t, of, 2 * (b * T + t), n, p, v, W, g, acc, buf)
            t += 8 * k
        if t < L:
            flag = _kf21_track(z, out, b, 0, t, p, v, L, F, H, Q, R, AK, K, Pf, P0, out_scale)
        else:                           # (calling it for no step cost 100 ns a track)
            flag = _pad(z, out, b, 0, 0, 1, 2, L)
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
