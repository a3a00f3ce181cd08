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
the plain joint model.

Two kinds of kernel share one contract:

* ``fixed_ss_kernel(n, m, nz)`` / ``fixed_kf_kernel(n, m, nz)``: generated and compiled
  for one (n, m) of :data:`FIXED` and the structural zeros ``nz`` of the model's matrices
  (:func:`pattern`) -- loops of constant length (unrolled), the state and the matrices in
  stack scratch (:func:`stack_array`, registers in practice).  Tracks go in groups of eight
  (lanes).  Where the eight are whole rows (``axes = 1``) and run together, they run in
  *vector blocks*: one AVX-512 vector holds a value of all eight, a block is eight steps,
  z is read as eight vectors per lane and transposed in registers, the states transposed
  back and stored as they lie in ``out`` (:func:`_vtile_in`, :func:`_vtile_out`) -- about
  four times the scalar code's work per cycle.  The rest (the steps before the first aligned
  block and after the last, other axes, incomplete groups, a lane after its first gap in the
  Kalman filter) runs the same recursion on scalars.  The last argument, ``streaming``,
  selects non-temporal stores of ``out`` (outputs far larger than the cache): whole aligned
  vectors in the blocks, scalars elsewhere.
* ``ss_kernel`` / ``kf_kernel``: any (n, m), loops of run-time length.

The state is carried in float64 whatever the storage dtype; float32 only
halves the bytes streamed.  Steps ``t >= lengths[b]`` are written as NaN.
The model matrices are always float64, so each kernel compiles once per
storage dtype, and ``cache=True`` keeps the machine code between processes.

Every filter kernel returns the number of tracks whose output is not finite
or whose padding (``t >= lengths[b]``) holds an infinity, so the caller
checks the output-finiteness policy without another pass over the data.  The
test is free: the recursions propagate a NaN or infinity to every later state
(0 * inf and inf - inf are NaN), so a track's output is finite exactly when its
last state is; float32 storage also keeps the largest magnitude it stores
(a finite float64 state above the float32 range is stored as an infinity).
"""

from __future__ import annotations

import functools

import numba as nb
import numpy as np
from numba import carray

from .. import _jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from ._intrinsics import (LANES8, address, load, many, mor, narrow, stack_array, store, store_fence, stream, transpose8,
                          visnan, vload, vmaxabs, vmul, vadd, vselect, vsplat, vstore, vstream, vsub)

__all__ = ["ss_kernel", "kf_kernel", "fixed_ss_kernel", "fixed_kf_kernel", "pattern", "GENERATED", "FIXED",
           "fir_kernel", "matvec_kernel", "copy_kernel"]

_OPTS = dict(parallel=True, cache=True, nogil=True, boundscheck=False)
_F32_MAX = float(np.finfo(np.float32).max)

#: The (n, m) with generated kernels: model B per axis, model A in 2-D and 3-D (Assimakis & Adam 2014).
FIXED = ((2, 1), (4, 2), (6, 3))


@nb.njit(cache=True, nogil=True)
def track_end(zf, of, zrow, xrow, mz, nx, m, n, L, T, largest):
    """Finish a track whose steps t < L are written: NaN for t >= L, and 1 when the track breaks
    the finiteness policy (an infinite padding value, a non-finite last state, or a stored float32
    magnitude ``largest`` above the float32 range), else 0.

    ``zrow``/``xrow`` are the flat indices of z[b, 0, axis * m] and out[b, 0, axis * n]; ``mz``,
    ``nx`` the widths of a time row of z and out."""
    bad = False
    for t in range(L, T):
        for c in range(m):
            bad |= np.isinf(load(zf, zrow + t * mz + c))
        for r in range(n):
            store(of, xrow + t * nx + r, np.nan)
    if L > 0:
        for r in range(n):
            bad |= not np.isfinite(load(of, xrow + (L - 1) * nx + r))
    return 1 if bad or largest > _F32_MAX else 0


@nb.njit(**_OPTS)
def ss_kernel(z, out, A, Bm, F, x0, lengths, axes):
    """x(k/k) = A x(k-1/k-1) + B z(k) (Assimakis & Adam 2014, eq. 9); a row with NaN predicts, x = F x.
    Returns the number of tracks breaking the finiteness policy (see the module docstring)."""
    nb_, T = z.shape[0], z.shape[1]
    n = A.shape[0]
    m = Bm.shape[1]
    mz, nx = z.shape[2], out.shape[2]
    zf, of = z.reshape(-1), out.reshape(-1)
    bad = 0
    for i in nb.prange(nb_ * axes):
        b = i // axes
        zo = (i - b * axes) * m
        xo = (i - b * axes) * n
        x = np.empty(n)
        xn = np.empty(n)
        for r in range(n):
            x[r] = x0[b, xo + r]
        L = lengths[b]
        largest = 0.0
        for t in range(L):
            miss = False
            for c in range(m):
                if np.isnan(z[b, t, zo + c]):
                    miss = True
            if miss:
                for r in range(n):
                    s = F[r, 0] * x[0]
                    for c in range(1, n):
                        s += F[r, c] * x[c]
                    xn[r] = s
            else:
                for r in range(n):
                    s = A[r, 0] * x[0]
                    for c in range(1, n):
                        s += A[r, c] * x[c]
                    u = Bm[r, 0] * z[b, t, zo]
                    for c in range(1, m):
                        u += Bm[r, c] * z[b, t, zo + c]
                    xn[r] = s + u
            for r in range(n):
                x[r] = xn[r]
                out[b, t, xo + r] = xn[r]
                if narrow(out):
                    largest = max(largest, abs(xn[r]))
        bad += track_end(zf, of, (b * T) * mz + zo, (b * T) * nx + xo, mz, nx, m, n, L, T, largest)
    return bad


@nb.njit(cache=True, nogil=True)
def kf_predict(F, Q, x, P):
    """x(k/k-1) = F x, P(k/k-1) = F P F^T + Q (new arrays)."""
    n = F.shape[0]
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
    return xp, Pp


@nb.njit(cache=True, nogil=True)
def observed(zrow, zo, m):
    """Indices c < m with zrow[zo + c] not NaN, and their count."""
    ok = np.empty(m, dtype=np.int64)
    k = 0
    for c in range(m):
        if not np.isnan(zrow[zo + c]):
            ok[k] = c
            k += 1
    return ok, k


@nb.njit(cache=True, nogil=True)
def kf_update(xp, Pp, Hs, Rs, innov, x, P):
    """Measurement update with the (k, n) matrix Hs, (k, k) noise Rs and innovation (k,):
    K = P H^T S^{-1} (S = H P H^T + R by Cholesky), x = xp + K innov, P = Pp - K H Pp,
    written into x and P (symmetrised).  Explicit loops keep numba's compile time low."""
    n = xp.shape[0]
    k = innov.shape[0]
    PHt = np.zeros((n, k))          # P(k/k-1) H^T
    for r in range(n):
        for i in range(k):
            for j in range(n):
                PHt[r, i] += Pp[r, j] * Hs[i, j]
    Lc = np.zeros((k, k))           # S = H P H^T + R = Lc Lc^T
    for i in range(k):
        for j in range(i + 1):
            s = Rs[i, j]
            for c in range(n):
                s += Hs[i, c] * PHt[c, j]
            for c in range(j):
                s -= Lc[i, c] * Lc[j, c]
            Lc[i, j] = np.sqrt(s) if i == j else s / Lc[j, j]
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


@nb.njit(cache=True, nogil=True)
def _kf_full_update(F, H, Q, R, x, P, zrow, zo):
    """One Kalman step (Assimakis & Adam 2014, eq. 4) with this track's own covariance P (in place).

    NaN components of the measurement are skipped; a fully missing row only predicts.
    """
    n = F.shape[0]
    xp, Pp = kf_predict(F, Q, x, P)
    ok, k = observed(zrow, zo, H.shape[0])
    if k == 0:
        x[:] = xp
        for r in range(n):
            for c in range(n):
                P[r, c] = Pp[r, c]
        return
    Hs = np.empty((k, n))
    Rs = np.empty((k, k))
    innov = np.empty(k)
    for i in range(k):
        s = zrow[zo + ok[i]]
        for j in range(n):
            Hs[i, j] = H[ok[i], j]
            s -= H[ok[i], j] * xp[j]
        innov[i] = s
        for j in range(k):
            Rs[i, j] = R[ok[i], ok[j]]
    kf_update(xp, Pp, Hs, Rs, innov, x, P)


@nb.njit(**_OPTS)
def kf_kernel(z, out, F, H, Q, R, K, Pf, P0, x0, lengths, axes):
    """Kalman filter with the shared gain sequence K[t] (Assimakis & Adam 2014, eq. 4).

    While a track's measurements are complete it uses the precomputed gains:
    x(k/k-1) = F x(k-1/k-1), x(k/k) = x(k/k-1) + K(k) [z(k) - H x(k/k-1)].
    At its first missing component it leaves the shared sequence: it takes
    P(k-1/k-1) = Pf[k-1] (or P0) and runs its own Riccati recursion from there.
    Returns the number of tracks breaking the finiteness policy.
    """
    nb_, T = z.shape[0], z.shape[1]
    n = F.shape[0]
    m = H.shape[0]
    mz, nx = z.shape[2], out.shape[2]
    zf, of = z.reshape(-1), out.reshape(-1)
    bad = 0
    for i in nb.prange(nb_ * axes):
        b = i // axes
        zo = (i - b * axes) * m
        xo = (i - b * axes) * n
        x = np.empty(n)
        for r in range(n):
            x[r] = x0[b, xo + r]
        L = lengths[b]
        largest = 0.0
        t1 = _kf_shared(z, out, F, H, K, x, b, zo, xo, 0, L)
        if narrow(out):
            for t in range(t1):
                for r in range(n):
                    largest = max(largest, abs(out[b, t, xo + r]))
        if t1 < L:
            P = P0.copy() if t1 == 0 else Pf[t1 - 1].copy()
            largest = max(largest, _kf_own(z, out, F, H, Q, R, x, P, b, zo, xo, t1, L))
        bad += track_end(zf, of, (b * T) * mz + zo, (b * T) * nx + xo, mz, nx, m, n, L, T, largest)
    return bad


@nb.njit(cache=True, nogil=True)
def _kf_shared(z, out, F, H, K, x, b, zo, xo, t0, L):
    """Steps t0 .. of track (b, axis) with the shared gains, state x (in place), until its first
    missing component; returns that time index (L when there is none)."""
    n = F.shape[0]
    m = H.shape[0]
    xp = np.empty(n)
    innov = np.empty(m)
    for t in range(t0, L):
        for c in range(m):
            if np.isnan(z[b, t, zo + c]):
                return t
        for r in range(n):
            s = F[r, 0] * x[0]
            for c in range(1, n):
                s += F[r, c] * x[c]
            xp[r] = s
        for c in range(m):
            s = H[c, 0] * xp[0]
            for j in range(1, n):
                s += H[c, j] * xp[j]
            innov[c] = z[b, t, zo + c] - s
        for r in range(n):
            s = K[t, r, 0] * innov[0]
            for c in range(1, m):
                s += K[t, r, c] * innov[c]
            x[r] = xp[r] + s
            out[b, t, xo + r] = x[r]
    return L


@nb.njit(cache=True, nogil=True)
def _kf_own(z, out, F, H, Q, R, x, P, b, zo, xo, t0, L):
    """Steps t0 .. L-1 of track (b, axis) with its own covariance P (from P(t0-1/t0-1)), state x;
    returns the largest magnitude written (for the float32 range check)."""
    n = F.shape[0]
    largest = 0.0
    for t in range(t0, L):
        _kf_full_update(F, H, Q, R, x, P, z[b, t], zo)
        for r in range(n):
            out[b, t, xo + r] = x[r]
            largest = max(largest, abs(x[r]))
    return largest


# Helpers of the generated kernels, inlined into them (numba IR), so that the stack scratch they
# work on stays in the kernel's frame and, with constant sizes, in registers.
_INLINE = dict(cache=True, nogil=True, inline="always")
B_, AXIS, ZROW, XROW, LEN = range(5)   # rows of a group's ``lane`` table


@nb.njit(**_INLINE)
def _lanes(i0, ntr, axes, T, mz, nx, m, lengths, x0, lane, x, big):
    """Set up the group of tracks i0 .. i0+W-1 (W = len(big); the last group may have fewer, ``nw``):
    ``lane`` rows (batch index, axis, flat index of z[b, 0, axis*m] and of out[b, 0, axis*n],
    length), the prior x and the float32 range trackers.  Returns (nw, the length all W lanes
    run together: the shortest, 0 for an incomplete group)."""
    W, n = x.shape
    nw = min(W, ntr - i0)
    together = T
    for w in range(W):
        i = i0 + min(w, nw - 1)
        b = i // axes
        a = i - b * axes
        lane[B_, w] = b
        lane[AXIS, w] = a
        lane[ZROW, w] = (b * T) * mz + a * m
        lane[XROW, w] = (b * T) * nx + a * n
        lane[LEN, w] = lengths[b]
        together = min(together, lengths[b])
        big[w] = 0.0
        for r in range(n):
            x[w, r] = x0[b, a * n + r]
    return nw, (together if nw == W else 0)


@nb.njit(**_INLINE)
def _measure(zf, lane, w, t, mz, zz):
    """zz[w] = z of lane w at step t; True when a component is missing (NaN)."""
    miss = False
    for c in range(zz.shape[1]):
        zz[w, c] = load(zf, lane[ZROW, w] + t * mz + c)
        miss |= np.isnan(zz[w, c])
    return miss


@nb.njit(**_INLINE)
def _matvec(M, nz, x, w, r):
    """(M x[w])[r], summed left to right over the entries of row r that are not structural zeros:
    bit r * cols + c of the constant ``nz`` is set for entry (r, c) (:func:`pattern`); 0.0 for a
    zero row.  (Bits of an integer fold away once the loops are unrolled; a tuple would not.)"""
    cols = M.shape[1]
    s = 0.0
    first = True
    for c in range(cols):
        if (nz >> (r * cols + c)) & 1:
            if first:
                s = M[r, c] * x[w, c]
                first = False
            else:
                s += M[r, c] * x[w, c]
    return s


@nb.njit(**_INLINE)
def _ss_step(a, bm, f, nz, x, xn, zz, w, miss):
    """xn[w] = A x[w] + B zz[w] (F x[w] when the measurement is missing); nz = patterns of A, B, F."""
    for r in range(x.shape[1]):
        if miss:
            xn[w, r] = _matvec(f, nz[2], x, w, r)
        else:
            xn[w, r] = _matvec(a, nz[0], x, w, r) + _matvec(bm, nz[1], zz, w, r)


@nb.njit(**_INLINE)
def _kf_step(f, h, k, nz, x, xn, e, w):
    """xn[w] = F x[w] + K (zz[w] - H F x[w]) with the shared gain k; ``e`` holds zz on entry;
    nz = patterns of F, H, K."""
    for r in range(x.shape[1]):
        xn[w, r] = _matvec(f, nz[0], x, w, r)
    for c in range(e.shape[1]):
        e[w, c] = e[w, c] - _matvec(h, nz[1], xn, w, c)
    for r in range(x.shape[1]):
        xn[w, r] = xn[w, r] + _matvec(k, nz[2], e, w, r)


@nb.njit(**_INLINE)
def _put(of, lane, w, t, nx, x, xn, big, streaming, narrow_out):
    """x[w] = xn[w], written as lane w's state at step t; with float32 storage keep its largest
    magnitude.  (One loop: a separate copy loop would become a memcpy that keeps x in memory.)"""
    for r in range(x.shape[1]):
        x[w, r] = xn[w, r]
        j = lane[XROW, w] + t * nx + r
        if streaming:
            stream(of, j, xn[w, r])
        else:
            store(of, j, xn[w, r])
        if narrow_out:
            big[w] = max(big[w], abs(xn[w, r]))


@nb.njit(**_INLINE)
def _pick(x, w, y, big, ybig):
    """y[0] = x[w], ybig[0] = big[w], reading x and big at constant indices only (a run-time
    index anywhere would keep the lanes' states out of registers in the main loop)."""
    for v in range(x.shape[0]):
        if v == w:
            ybig[0] = big[v]
            for r in range(x.shape[1]):
                y[0, r] = x[v, r]


@nb.njit(**_INLINE)
def _copy(src, dst):
    for r in range(dst.shape[0]):
        for c in range(dst.shape[1]):
            dst[r, c] = src[r, c]


def pattern(*matrices, keep=()) -> tuple:
    """The structural-zero patterns of matrices (n, k) or stacks of them (T, n, k), one integer
    each: bit r * k + c is set where entry (r, c) is not zero (in some matrix of a stack).  A
    kernel generated for the patterns skips the zero terms: its sums are those of the dense
    product except for the sign of a zero.  Matrices in ``keep`` must keep their diagonal (else
    they count as dense), so that a NaN or infinity in a state component stays in it (the
    finiteness test looks at the last state only)."""
    out = []
    for i, M in enumerate(matrices):
        nz = np.asarray(M) != 0
        if nz.ndim == 3:
            nz = nz.any(axis=0)
        if i in keep and not nz.diagonal().all():
            nz = np.ones_like(nz)
        out.append(int(np.dot(nz.ravel().astype(np.int64), 1 << np.arange(nz.size, dtype=np.int64))))
    return tuple(out)


#: The generated kernels made in this process, by their factory and arguments.
GENERATED: dict = {}


def _generated(factory):
    """Make each kernel once per process (numba's cache keeps the machine code between them)."""
    @functools.wraps(factory)
    def get(*args):
        key = (factory.__name__, *args)
        if key not in GENERATED:
            GENERATED[key] = factory(*args)
        return GENERATED[key]
    return get


@nb.njit(**_INLINE)
def _ss_together(a, bm, f, nz, zf, of, lane, x, xn, zz, big, t, stop, mz, nx, streaming, narrow_out):
    """Steps t .. stop-1 of all lanes with the scalar code, until a lane's measurement has a
    NaN; returns the first step not done."""
    while t < stop:
        miss = False
        for w in range(x.shape[0]):
            miss |= _measure(zf, lane, w, t, mz, zz)
        if miss:
            break
        for w in range(x.shape[0]):
            _ss_step(a, bm, f, nz, x, xn, zz, w, False)
            _put(of, lane, w, t, nx, x, xn, big, streaming, narrow_out)
        t += 1
    return t


@nb.njit(**_INLINE)
def _kf_together(f, h, k, K, nz, zf, of, lane, x, xn, e, big, t, stop, mz, nx, streaming, narrow_out):
    """As :func:`_ss_together` for the shared-gain Kalman step."""
    while t < stop:
        miss = False
        for w in range(x.shape[0]):
            miss |= _measure(zf, lane, w, t, mz, e)
        if miss:
            break
        _copy(K[t], k)
        for w in range(x.shape[0]):
            _kf_step(f, h, k, nz, x, xn, e, w)
            _put(of, lane, w, t, nx, x, xn, big, streaming, narrow_out)
        t += 1
    return t


# --- the vector path: eight tracks in one vector, eight steps per block --------------------------
#
# A block reads z of the eight lanes for eight steps (m vectors per lane: contiguous when the
# tracks are whole rows, axes = 1), transposes them to one vector per (step, component), runs
# the recursion on those vectors and transposes the states back to n vectors per lane, stored
# as they lie in ``out``.  The buffers are stack arrays of whole vectors: ``V[(i) * 8:(i + 1) * 8]``
# is vector i.  Arithmetic in the scalar path's order (separate multiply and add, the same
# structural zeros skipped), so a track's numbers do not depend on the path.

@nb.njit(**_INLINE)
def _vmatvec(M, nz, V, base, r):
    """(M v)[r] for eight lanes, component c of v being vector base + c of V (see :func:`_matvec`)."""
    cols = M.shape[1]
    s = vsplat(0.0)
    first = True
    for c in range(cols):
        if (nz >> (r * cols + c)) & 1:
            term = vmul(vsplat(M[r, c]), vload(V, (base + c) * LANES8))
            if first:
                s = term
                first = False
            else:
                s = vadd(s, term)
    return s


@nb.njit(**_INLINE)
def _vlane(arr, lane, row, offset):
    """The eight lanes' vectors at ``arr[lane[row, w] + offset:][:8]``, w = 0..7, transposed: vector j
    holds element j of every lane."""
    return transpose8((vload(arr, lane[row, 0] + offset), vload(arr, lane[row, 1] + offset),
                       vload(arr, lane[row, 2] + offset), vload(arr, lane[row, 3] + offset),
                       vload(arr, lane[row, 4] + offset), vload(arr, lane[row, 5] + offset),
                       vload(arr, lane[row, 6] + offset), vload(arr, lane[row, 7] + offset)))


@nb.njit(**_INLINE)
def _vtile_in(zf, lane, t, m, ZT):
    """ZT vector tt * m + c = component c of z at step t + tt of the eight lanes (tt < 8)."""
    for k in range(m):
        cols = _vlane(zf, lane, ZROW, t * m + LANES8 * k)
        for j in range(LANES8):
            vstore(ZT, (LANES8 * k + j) * LANES8, cols[j])


@nb.njit(**_INLINE)
def _vnan(V, count):
    """True when one of the first ``count`` vectors of V has a NaN."""
    miss = visnan(vload(V, 0))
    for j in range(1, count):
        miss = mor(miss, visnan(vload(V, j * LANES8)))
    return many(miss)


@nb.njit(**_INLINE)
def _vcopy(src, dst, count):
    for j in range(count):
        vstore(dst, j * LANES8, vload(src, j * LANES8))


@nb.njit(**_INLINE)
def _vtile_out(of, lane, t, n, XT, streaming):
    """Store XT (vector tt * n + r = component r of the state at step t + tt) into the lanes' rows."""
    for k in range(n):
        base = LANES8 * k * LANES8
        rows = transpose8((vload(XT, base), vload(XT, base + 8), vload(XT, base + 16), vload(XT, base + 24),
                           vload(XT, base + 32), vload(XT, base + 40), vload(XT, base + 48),
                           vload(XT, base + 56)))
        for w in range(LANES8):
            j = lane[XROW, w] + t * n + LANES8 * k
            if streaming:
                vstream(of, j, rows[w])
            else:
                vstore(of, j, rows[w])


@nb.njit(**_INLINE)
def _vstate(S, XT, tt, n, big, narrow_out):
    """The state after step tt becomes the current one (S); float32 storage tracks its magnitude."""
    for r in range(n):
        v = vload(XT, (tt * n + r) * LANES8)
        vstore(S, r * LANES8, v)
        if narrow_out:
            vstore(big, 0, vmaxabs(vload(big, 0), v))


@nb.njit(**_INLINE)
def _vss_block(a, bm, f, nz, S, XT, ZT, big, narrow_out):
    """Eight steady-state steps of eight lanes, x = A x + B z (no NaN in ZT)."""
    n, m = a.shape[0], bm.shape[1]
    for tt in range(LANES8):
        for r in range(n):
            vstore(XT, (tt * n + r) * LANES8, vadd(_vmatvec(a, nz[0], S, 0, r), _vmatvec(bm, nz[1], ZT, tt * m, r)))
        _vstate(S, XT, tt, n, big, narrow_out)


@nb.njit(**_INLINE)
def _vss_gaps_block(a, bm, f, nz, S, XT, ZT, big, narrow_out):
    """As :func:`_vss_block` where ZT has a NaN: x = F x in the lanes whose z has one.  (A separate
    loop: with the test in the loop of the complete blocks, LLVM keeps that loop rolled and
    its vectors in memory, 1.6x slower.)"""
    n, m = a.shape[0], bm.shape[1]
    for tt in range(LANES8):
        miss = visnan(vload(ZT, tt * m * LANES8))
        for c in range(1, m):
            miss = mor(miss, visnan(vload(ZT, (tt * m + c) * LANES8)))
        for r in range(n):
            x = vadd(_vmatvec(a, nz[0], S, 0, r), _vmatvec(bm, nz[1], ZT, tt * m, r))
            vstore(XT, (tt * n + r) * LANES8, vselect(miss, _vmatvec(f, nz[2], S, 0, r), x))
        _vstate(S, XT, tt, n, big, narrow_out)


@nb.njit(**_INLINE)
def _vkf_block(f, h, K, t, nz, S, XT, ZT, XP, E, big, narrow_out):
    """Eight shared-gain Kalman steps of eight lanes (no NaN in ZT): x = F x + K (z - H F x)."""
    n, m = f.shape[0], h.shape[0]
    for tt in range(LANES8):
        k = K[t + tt]
        for r in range(n):
            vstore(XP, r * LANES8, _vmatvec(f, nz[0], S, 0, r))
        for c in range(m):
            vstore(E, c * LANES8, vsub(vload(ZT, (tt * m + c) * LANES8), _vmatvec(h, nz[1], XP, 0, c)))
        for r in range(n):
            vstore(XT, (tt * n + r) * LANES8, vadd(vload(XP, r * LANES8), _vmatvec(k, nz[2], E, 0, r)))
        _vstate(S, XT, tt, n, big, narrow_out)


@nb.njit(**_INLINE)
def _pack(x, S):
    """S vector r = component r of the lanes' states x[w, r] (and back: :func:`_unpack`)."""
    for r in range(x.shape[1]):
        for w in range(LANES8):
            S[r * LANES8 + w] = x[w, r]


@nb.njit(**_INLINE)
def _unpack(S, x):
    for r in range(x.shape[1]):
        for w in range(LANES8):
            x[w, r] = S[r * LANES8 + w]


@nb.njit(**_INLINE)
def _vector_start(of, lane, n, together, axes, nw, streaming):
    """The step at which the group's vector blocks start, or -1 for none: the eight lanes must be
    whole rows (axes = 1) running together for a block; with non-temporal stores each lane's
    output address at that step must be aligned to a vector's size (the same step for all)."""
    if axes != 1 or nw != LANES8:
        return -1
    if not streaming:
        return 0 if together >= LANES8 else -1
    size = of.itemsize
    base = address(of)
    for t0 in range(LANES8):
        aligned = True
        for w in range(LANES8):
            aligned &= (base + (lane[XROW, w] + t0 * n) * size) % (LANES8 * size) == 0
        if aligned:
            return t0 if t0 + LANES8 <= together else -1
    return -1


def _feeds(nz: int, rows: int, cols: int) -> bool:
    """True when every column of the (rows, cols) zero pattern ``nz`` of B or K has a non-zero.

    A vector block then looks for a NaN in its z through the states it computed: every
    component of z enters them (through B, or K), and a NaN stays in its state component (the
    diagonal of A and F is kept, :func:`pattern`), so a block whose last states have no NaN had
    none in z; checking the states costs n tests, z 8 m (1 ms of 8 per 10^7 steps of model B)."""
    return all(any((nz >> (r * cols + c)) & 1 for r in range(rows)) for c in range(cols))


@_generated
def fixed_ss_kernel(n: int, m: int, nz: tuple):
    """:func:`ss_kernel` compiled for one (n, m) of :data:`FIXED` (see the module docstring) and
    the zero patterns ``nz`` of (A, B, F) (:func:`pattern`).

    Eight tracks (lanes) advance together: in vector blocks of eight steps where they can
    (:func:`_vector_start`; a NaN predicts in its lane), else with the scalar code while all of
    them have a measurement; at a NaN there, or when the shortest of them ends, each lane
    finishes alone."""
    W = LANES8
    NN, NM, WN, WM, W5 = n * n, n * m, W * n, W * m, 5 * W
    SV, XV, ZV = n * W, W * n * W, W * m * W        # vector buffers: state, a block's states, its z
    FEEDS = _feeds(nz[1], n, m)

    @nb.njit(cache=True, nogil=True)
    def group(g, zf, of, A, Bm, F, x0, lengths, axes, ntr, T, mz, nx, streaming):
        """Lane group g (tracks 8g .. 8g + 7); returns how many break the finiteness policy."""
        a = carray(stack_array(NN, np.float64), (n, n))
        f = carray(stack_array(NN, np.float64), (n, n))
        bm = carray(stack_array(NM, np.float64), (n, m))
        _copy(A, a)
        _copy(F, f)
        _copy(Bm, bm)
        lane = carray(stack_array(W5, np.int64), (5, W))
        x = carray(stack_array(WN, np.float64), (W, n))
        xn = carray(stack_array(WN, np.float64), (W, n))
        zz = carray(stack_array(WM, np.float64), (W, m))
        big = carray(stack_array(W, np.float64), W)
        nw, together = _lanes(g * W, ntr, axes, T, mz, nx, m, lengths, x0, lane, x, big)
        t0 = _vector_start(of, lane, n, together, axes, nw, streaming)
        if t0 < 0:
            t = _ss_together(a, bm, f, nz, zf, of, lane, x, xn, zz, big, 0, together, mz, nx, streaming,
                             narrow(of))
        else:       # the scalar steps around the blocks write parts of lines: no non-temporal stores
            t = _ss_together(a, bm, f, nz, zf, of, lane, x, xn, zz, big, 0, t0, mz, nx, False, narrow(of))
            if t == t0:
                S = carray(stack_array(SV, np.float64), SV)
                S0 = carray(stack_array(SV, np.float64), SV)
                XT = carray(stack_array(XV, np.float64), XV)
                ZT = carray(stack_array(ZV, np.float64), ZV)
                _pack(x, S)
                while t + W <= together:
                    _vtile_in(zf, lane, t, m, ZT)
                    _vcopy(S, S0, n)
                    _vss_block(a, bm, f, nz, S, XT, ZT, big, narrow(of))
                    if _vnan(S, n) if FEEDS else _vnan(ZT, W * m):     # a NaN in z (see _feeds)
                        _vcopy(S0, S, n)
                        _vss_gaps_block(a, bm, f, nz, S, XT, ZT, big, narrow(of))
                    _vtile_out(of, lane, t, n, XT, streaming)
                    t += W
                _unpack(S, x)
            t = _ss_together(a, bm, f, nz, zf, of, lane, x, xn, zz, big, t, together, mz, nx, False, narrow(of))
        bad = 0
        y = carray(stack_array(n, np.float64), (1, n))      # one lane finishing alone
        yn = carray(stack_array(n, np.float64), (1, n))
        y1 = carray(stack_array(m, np.float64), (1, m))
        ybig = carray(stack_array(1, np.float64), 1)
        for w in range(nw):
            _pick(x, w, y, big, ybig)
            lane1 = lane[:, w:w + 1]
            L = lane1[LEN, 0]
            for tt in range(t, L):
                _ss_step(a, bm, f, nz, y, yn, y1, 0, _measure(zf, lane1, 0, tt, mz, y1))
                _put(of, lane1, 0, tt, nx, y, yn, ybig, streaming, narrow(of))
            bad += track_end(zf, of, lane1[ZROW, 0], lane1[XROW, 0], mz, nx, m, n, L, T, ybig[0])
        return bad

    @nb.njit(**_OPTS)
    def kernel(z, out, A, Bm, F, x0, lengths, axes, streaming):
        zf, of = z.reshape(-1), out.reshape(-1)
        ntr = z.shape[0] * axes
        bad = 0
        for g in nb.prange((ntr + W - 1) // W):
            bad += group(g, zf, of, A, Bm, F, x0, lengths, axes, ntr, z.shape[1], z.shape[2], out.shape[2],
                         streaming)
            if streaming:
                store_fence()
        return bad

    return kernel


@_generated
def fixed_kf_kernel(n: int, m: int, nz: tuple):
    """:func:`kf_kernel` compiled for one (n, m) of :data:`FIXED` and the zero patterns ``nz`` of
    (F, H, K) (see :func:`fixed_ss_kernel`).

    The vector blocks stop at the first NaN of any lane; a lane that meets a missing component
    finishes alone: with the shared gains up to it, then with its own covariance (as
    :func:`kf_kernel`)."""
    W = LANES8
    NN, MN, NM, WN, WM, W5 = n * n, m * n, n * m, W * n, W * m, 5 * W
    SV, XV, ZV, EV = n * W, W * n * W, W * m * W, m * W
    FEEDS = _feeds(nz[2], n, m)

    @nb.njit(cache=True, nogil=True)
    def group(g, z, out, zf, of, F, H, Q, R, K, Pf, P0, x0, lengths, axes, ntr, T, mz, nx, streaming):
        """Lane group g (tracks 8g .. 8g + 7); returns how many break the finiteness policy."""
        f = carray(stack_array(NN, np.float64), (n, n))
        h = carray(stack_array(MN, np.float64), (m, n))
        k = carray(stack_array(NM, np.float64), (n, m))
        _copy(F, f)
        _copy(H, h)
        lane = carray(stack_array(W5, np.int64), (5, W))
        x = carray(stack_array(WN, np.float64), (W, n))
        xn = carray(stack_array(WN, np.float64), (W, n))
        e = carray(stack_array(WM, np.float64), (W, m))
        big = carray(stack_array(W, np.float64), W)
        nw, together = _lanes(g * W, ntr, axes, T, mz, nx, m, lengths, x0, lane, x, big)
        t0 = _vector_start(of, lane, n, together, axes, nw, streaming)
        if t0 < 0:
            t = _kf_together(f, h, k, K, nz, zf, of, lane, x, xn, e, big, 0, together, mz, nx, streaming,
                             narrow(of))
        else:       # the scalar steps around the blocks write parts of lines: no non-temporal stores
            t = _kf_together(f, h, k, K, nz, zf, of, lane, x, xn, e, big, 0, t0, mz, nx, False, narrow(of))
            if t == t0:
                S = carray(stack_array(SV, np.float64), SV)
                XT = carray(stack_array(XV, np.float64), XV)
                ZT = carray(stack_array(ZV, np.float64), ZV)
                XP = carray(stack_array(SV, np.float64), SV)
                E = carray(stack_array(EV, np.float64), EV)
                S0 = carray(stack_array(SV, np.float64), SV)
                _pack(x, S)
                while t + W <= together:
                    _vtile_in(zf, lane, t, m, ZT)
                    _vcopy(S, S0, n)
                    _vkf_block(f, h, K, t, nz, S, XT, ZT, XP, E, big, narrow(of))
                    if _vnan(S, n) if FEEDS else _vnan(ZT, W * m):     # a NaN in z: the scalar code
                        _vcopy(S0, S, n)                                # takes over at this block
                        break
                    _vtile_out(of, lane, t, n, XT, streaming)
                    t += W
                _unpack(S, x)
            t = _kf_together(f, h, k, K, nz, zf, of, lane, x, xn, e, big, t, together, mz, nx, False, narrow(of))
        bad = 0
        y = carray(stack_array(n, np.float64), (1, n))      # one lane finishing alone
        yn = carray(stack_array(n, np.float64), (1, n))
        y1 = carray(stack_array(m, np.float64), (1, m))
        ybig = carray(stack_array(1, np.float64), 1)
        for w in range(nw):
            _pick(x, w, y, big, ybig)
            lane1 = lane[:, w:w + 1]
            L = lane1[LEN, 0]
            tt = t
            while tt < L and not _measure(zf, lane1, 0, tt, mz, y1):
                _copy(K[tt], k)
                _kf_step(f, h, k, nz, y, yn, y1, 0)
                _put(of, lane1, 0, tt, nx, y, yn, ybig, streaming, narrow(of))
                tt += 1
            if tt < L:            # the first gap: leave the shared gains
                xv = np.empty(n)
                for r in range(n):
                    xv[r] = y[0, r]
                P = P0.copy() if tt == 0 else Pf[tt - 1].copy()
                b, a = lane1[B_, 0], lane1[AXIS, 0]
                ybig[0] = max(ybig[0], _kf_own(z, out, F, H, Q, R, xv, P, b, a * m, a * n, tt, L))
            bad += track_end(zf, of, lane1[ZROW, 0], lane1[XROW, 0], mz, nx, m, n, L, T, ybig[0])
        return bad

    @nb.njit(**_OPTS)
    def kernel(z, out, F, H, Q, R, K, Pf, P0, x0, lengths, axes, streaming):
        zf, of = z.reshape(-1), out.reshape(-1)
        ntr = z.shape[0] * axes
        bad = 0
        for g in nb.prange((ntr + W - 1) // W):
            bad += group(g, z, out, zf, of, F, H, Q, R, K, Pf, P0, x0, lengths, axes, ntr, z.shape[1],
                         z.shape[2], out.shape[2], streaming)
            if streaming:
                store_fence()
        return bad

    return kernel


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
