"""The likelihood that noise estimation maximises, for every track in one compiled pass.

:func:`loglik_tracks` gives, per track, the pieces (E, L, N) of the Gaussian
log-likelihood of the innovations of the fixes a mask accepts -- the sum of
their NIS, of log det S and their count -- conditional on the first ``order``
fixes of each stretch: an exact diffuse start in information form (Durbin &
Koopman 2012, sec. 5.2), so the likelihood depends on the data and the noise
only, not on a prior, and the noise scale can be concentrated out of it
(:mod:`._noise`).  :func:`moment_guess` is the method-of-moments start of
that search.  The filter steps are the integrator-chain algebra of
:mod:`._chain`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ._chain import (BLOCKS, INLINE, M_F, M_P, M_PC, M_PP, M_QU, M_T, M_UA, M_UT, PAR, S_X, S_XC, S_XP, SEQ, V_UK,
                     chain_transition, copy_state, info_start, predict, update, work)

__all__ = ["USE", "SKIP", "RESTART", "loglik_tracks", "moment_guess"]

#: Mask codes of :func:`loglik_tracks`: a fix is used, left out, or starts a new stretch.
USE, SKIP, RESTART = 0, 1, 2


@nb.njit(**INLINE)
def _diffuse_start(k, t, ze, zn, w, mask, c, q, order, x, P, wk):
    """Collect the next ``order`` accepted fixes from row k on (a RESTART begins the collection
    again) and start from them (:func:`info_start`).  Returns the row after the last of them, or
    -1 if the rows run out first."""
    n = t.shape[0]
    rows = wk[4]
    count = 0
    while k < n:
        code = mask[k]
        if code != SKIP:
            if code == RESTART:
                count = 0
            rows[count] = k
            count += 1
            if count == order:
                if info_start(t, ze, zn, w, c, rows, order, q, order, order, 1.0, 1.0, x, P, wk):
                    return k + 1
                for j in range(order - 1):  # singular (equal times): slide the window on
                    rows[j] = rows[j + 1]
                count -= 1
        k += 1
    return -1


@nb.njit(**INLINE)
def _track_loglik(t, ze, zn, w, mask, c, q, order, out, wk):
    """out <- (E, L, N): sum of NIS, sum of log det S and number of scalar innovations of the fixes
    ``mask`` accepts, conditional on the first ``order`` accepted fixes of each stretch (a stretch
    starts at row 0 and at each RESTART)."""
    mats, st, vec, _, _ = wk
    F, Qu, tmp, P, Ps, Pp = mats[M_F], mats[M_QU], mats[M_T], mats[M_P], mats[M_PC], mats[M_PP]
    UA, UT, uk = mats[M_UA], mats[M_UT], vec[V_UK]
    x, xs, xp = st[S_X], st[S_XC], st[S_XP]
    E = 0.0
    L = 0.0
    N = 0.0
    n = t.shape[0]
    k = 0
    while k < n:
        k = _diffuse_start(k, t, ze, zn, w, mask, c, q, order, xs, Ps, wk)
        if k < 0:
            break
        copy_state(order, xs, Ps, x, P)
        t_last = t[k - 1]
        while k < n:           # the hot loop: no calls that are not inlined
            code = mask[k]
            if code == RESTART:
                break
            if code != SKIP:
                chain_transition(order, t[k] - t_last, F, Qu)
                predict(order, F, Qu, q, 0.0, x, P, xp, Pp, tmp)
                e, S = update(order, -1, xp, Pp, c * w[k], ze[k], zn[k], x, P, UA, UT, uk)
                E += e
                L += 2.0 * math.log(S)
                N += 2.0
                t_last = t[k]
            k += 1
    out[0] = E
    out[1] = L
    out[2] = N


# ---- the parallel kernel, compiled once per model order -------------------------------------------------

def _make_kernel(order: int):
    """The parallel kernel with ``order`` a compile-time constant (the small per-fix loops unroll;
    a runtime order made them 3x slower).  numba caches each closure per constant."""

    @nb.njit(**PAR)
    def loglik_kernel(offsets, active, t, ze, zn, w, mask, c, q, out):
        B = offsets.shape[0] - 1
        nblk = min(B, BLOCKS)
        for blk in nb.prange(nblk):
            wk = work(order, order)
            for b in range(blk * B // nblk, (blk + 1) * B // nblk):
                if not active[b]:
                    continue
                a0 = offsets[b]
                b0 = offsets[b + 1]
                _track_loglik(t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], mask[a0:b0], c[b], q[b], order, out[b], wk)

    return loglik_kernel


_KERNELS = {}


def loglik_tracks(offsets, active, t, ze, zn, w, mask, c, q, order, out):
    """(E, L, N) of :func:`_track_loglik` for every track b with active[b] (out (B, 3)); track b
    uses fix variances c[b] w[k] and process-noise density q[b]."""
    if order not in _KERNELS:
        if order not in (2, 3):
            raise ValueError(f"order: the engine runs integrator chains of order 2 or 3, got {order}")
        _KERNELS[order] = _make_kernel(order)
    _KERNELS[order](offsets, active, t, ze, zn, w, mask, c, q, out)


@nb.njit(**SEQ)
def _track_moments(t, ze, zn, w, mask, guess):
    """Method-of-moments start for (c, q): second divided differences D of the positions over
    consecutive accepted fixes have variance c (w2/h2^2 + w1 (1/h1 + 1/h2)^2 + w0/h1^2) +
    q (h1 + h2)/3 for a cv chain (integrated Brownian velocity); fitted by iteratively
    reweighted least squares with large residuals down-weighted.  guess <- (c, q, count)."""
    n = t.shape[0]
    idx = np.empty(n, dtype=np.int64)
    m = 0
    for k in range(n):
        if mask[k] != SKIP:
            idx[m] = k
            m += 1
    K = max(m - 2, 0)
    d2 = np.empty(2 * K)
    al = np.empty(2 * K)
    be = np.empty(2 * K)
    cnt = 0
    for j in range(1, m - 1):
        k0, k1, k2 = idx[j - 1], idx[j], idx[j + 1]
        if mask[k1] == RESTART or mask[k2] == RESTART:
            continue
        h1 = t[k1] - t[k0]
        h2 = t[k2] - t[k1]
        if not (h1 > 0.0 and h2 > 0.0):
            continue
        coef_c = w[k2] / (h2 * h2) + w[k1] * (1.0 / h1 + 1.0 / h2) ** 2 + w[k0] / (h1 * h1)
        coef_q = (h1 + h2) / 3.0
        for ax in range(2):
            z = ze if ax == 0 else zn
            d = (z[k2] - z[k1]) / h2 - (z[k1] - z[k0]) / h1
            d2[cnt] = d * d
            al[cnt] = coef_c
            be[cnt] = coef_q
            cnt += 1
    guess[2] = cnt
    if cnt < 2:
        guess[0] = np.nan
        guess[1] = np.nan
        return
    ra = np.empty(cnt)
    for i in range(cnt):
        ra[i] = d2[i] / al[i]
    c = 0.5 * np.median(ra) / 0.455
    for i in range(cnt):
        ra[i] = d2[i] / be[i]
    q = 0.5 * np.median(ra) / 0.455
    if not (c > 0.0 and q > 0.0 and np.isfinite(c) and np.isfinite(q)):
        guess[0] = np.nan   # fixes on one point or one exact line: no start (the search's default)
        guess[1] = np.nan
        return
    for _ in range(8):
        s_aa = s_ab = s_bb = s_ay = s_by = 0.0
        for i in range(cnt):
            v = c * al[i] + q * be[i]
            u = d2[i] / v
            wt = 1.0 / (v * v) * (1.0 if u < 9.0 else 9.0 / u)
            s_aa += wt * al[i] * al[i]
            s_ab += wt * al[i] * be[i]
            s_bb += wt * be[i] * be[i]
            s_ay += wt * al[i] * d2[i]
            s_by += wt * be[i] * d2[i]
        det = s_aa * s_bb - s_ab * s_ab
        if not det > 0.0:
            break
        cn = (s_bb * s_ay - s_ab * s_by) / det
        qn = (s_aa * s_by - s_ab * s_ay) / det
        # a negative component means the data do not resolve it: keep it small, not zero
        if cn <= 0.0:
            cn = 1e-3 * c
            qn = s_by / s_bb
        if qn <= 0.0:
            qn = 1e-3 * q
            cn = s_ay / s_aa
        if not (cn > 0.0 and qn > 0.0 and np.isfinite(cn) and np.isfinite(qn)):
            break
        c, q = cn, qn
    guess[0] = c
    guess[1] = q


@nb.njit(**PAR)
def moment_guess(offsets, t, ze, zn, w, mask, out):
    """out (B, 3) <- :func:`_track_moments` of every track."""
    B = offsets.shape[0] - 1
    for b in nb.prange(B):
        a0 = offsets[b]
        b0 = offsets[b + 1]
        _track_moments(t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], mask[a0:b0], out[b])
