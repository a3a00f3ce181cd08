"""The columnar tracking engine: one compiled pass over all tracks of a table of position fixes.

Layout (shared/DESIGN.md, "Many tracks"): the fixes of B tracks are flat
columns sorted by (track, time); track b is rows ``offsets[b]:offsets[b+1]``.
Every kernel here loops over tracks with ``prange`` and over a track's fixes
in order, and no Python runs per track.  The filter and likelihood kernels
split the tracks into blocks, and each block allocates one workspace
(:func:`_work`) for all its tracks, so they allocate nothing per track or per
fix; the method-of-moments start (:func:`moment_guess`, once per estimation)
allocates its scratch per track.

The motion models of ``mptrack track`` are integrator chains per axis (cv:
position, velocity; ca: + acceleration) driven by white noise of density q on
the highest derivative, with the same model on the east and north axes and an
isotropic fix noise R = r I.  Then the 2-D Kalman filter splits exactly into
two per-axis filters that share one covariance (it depends on the times and
r only), so the engine carries one (order x order) covariance and two means.
Each interval is discretised in closed form, F_ij = dt^(j-i)/(j-i)! and
Q_ij = q dt^p / (p (r-1-i)! (r-1-j)!), p = 2r-1-i-j (the exact Van Loan
result for an integrator chain of order r; Assimakis et al. 2016, sec. 2, for
r = 2, 3).  These are the models of ``mptrack track`` (:data:`MODELS`: cv, ca);
the per-track reference (:func:`~._fixes.track_fixes`) runs the general
continuous model and is what the engine is tested against.

Two kernels:

* :func:`filter_tracks` -- the gated filter of :mod:`._gated` (two-level NIS
  gate with a one-fix lookahead, restarts), optional RTS smoothing, per-track
  log-likelihood; equal to the per-track reference to rounding (tests).
* :func:`loglik_tracks` -- the log-likelihood pieces that noise estimation
  (:mod:`._noise`) maximises: the innovations of the fixes a mask accepts,
  conditional on the first ``order`` fixes of each segment (exact diffuse
  start in information form, Durbin & Koopman 2012, sec. 5.2), so the noise
  scale can be concentrated out of the likelihood.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

__all__ = ["FLAGS", "INIT", "UPDATE", "OUTLIER", "PREDICTED", "RESET", "MANOEUVRE", "MANOEUVRE_FACTOR",
           "MAX_ORDER", "filter_tracks",
           "loglik_tracks", "moment_guess", "chain_transition"]

#: Per-point flags of a tracking result (the output's ``flag`` column), by index.
FLAGS = ("update", "outlier", "predicted", "reset", "init", "manoeuvre")
UPDATE, OUTLIER, PREDICTED, RESET, INIT, MANOEUVRE = range(6)
#: Process noise of the manoeuvre hypothesis, as a multiple of the model's density q.
MANOEUVRE_FACTOR = 10.0
MAX_ORDER = 3
_LOG2PI = math.log(2.0 * math.pi)
# mask codes of loglik_tracks
USE, SKIP, RESTART = 0, 1, 2

# error_model="numpy": a division by zero gives inf/NaN as in NumPy (checked by the callers), not an exception
_PAR = dict(parallel=True, cache=True, nogil=True, boundscheck=False, error_model="numpy")
_SEQ = dict(cache=True, nogil=True, boundscheck=False, error_model="numpy")
# Inlined: the per-fix steps and the diffuse start (once per track, several calls): a call passes
# every array as ~7 scalars (the workspace tuple as ~240), which made short tracks 5x slower; the
# rest stays a call, as inlining everything took minutes to compile.
_INLINE = dict(_SEQ, inline="always")


@nb.njit(**_INLINE)
def chain_transition(order, dt, F, Qu):
    """F and the unit-density Q (q = 1) of an integrator chain of ``order`` (2 or 3) over ``dt`` seconds:
    F_ij = dt^(j-i)/(j-i)!, Qu_ij = dt^p / (p (r-1-i)! (r-1-j)!), p = 2r-1-i-j (written out)."""
    d2 = dt * dt
    d3 = d2 * dt
    if order == 2:
        F[0, 0] = 1.0
        F[0, 1] = dt
        F[1, 0] = 0.0
        F[1, 1] = 1.0
        Qu[0, 0] = d3 / 3.0
        Qu[0, 1] = d2 / 2.0
        Qu[1, 0] = d2 / 2.0
        Qu[1, 1] = dt
        return
    d4 = d3 * dt
    d5 = d4 * dt
    for i in range(3):
        for j in range(3):
            F[i, j] = 0.0
    F[0, 0] = F[1, 1] = F[2, 2] = 1.0
    F[0, 1] = F[1, 2] = dt
    F[0, 2] = d2 / 2.0
    Qu[0, 0] = d5 / 20.0
    Qu[0, 1] = Qu[1, 0] = d4 / 8.0
    Qu[0, 2] = Qu[2, 0] = d3 / 6.0
    Qu[1, 1] = d3 / 3.0
    Qu[1, 2] = Qu[2, 1] = d2 / 2.0
    Qu[2, 2] = dt


@nb.njit(**_INLINE)
def _product(order, A, B, out, ta, tb):
    """out = op(A) op(B) for order x order matrices, op(X) = X^T where ta / tb."""
    for i in range(order):
        for j in range(order):
            s = 0.0
            for m in range(order):
                s += (A[m, i] if ta else A[i, m]) * (B[j, m] if tb else B[m, j])
            out[i, j] = s


@nb.njit(**_INLINE)
def _congruence(order, A, B, T, base, scale, out):
    """out = A B A^T + scale * base, symmetric (T is scratch: it holds A B afterwards)."""
    _product(order, A, B, T, False, False)
    for i in range(order):
        for j in range(i, order):
            s = 0.0
            for m in range(order):
                s += T[i, m] * A[j, m]
            s += scale * base[i, j]
            out[i, j] = s
            out[j, i] = s


@nb.njit(**_INLINE)
def _predict(order, F, Qu, q, x, P, xp, Pp, T):
    """xp = F x (both axes), Pp = F P F^T + q Qu (T is scratch: F P afterwards)."""
    for a in range(2):
        for i in range(order):
            s = 0.0
            for j in range(order):
                s += F[i, j] * x[a, j]
            xp[a, i] = s
    _congruence(order, F, P, T, Qu, q, Pp)


@nb.njit(**_INLINE)
def _update(order, xp, Pp, r, ze, zn, x, P):
    """Kalman update of both axes with the fix (ze, zn) of variance r; returns (NIS, S).

    The rank-one form of :func:`mptrack._core.kalman.update` for H = [1, 0, ...] and one covariance
    shared by the two axes (S = P_00 + r, K = P[:, 0] / S), written out because it is inlined in the
    per-fix loop: a documented exception to the one compiled update, tested against it
    (tests/test_kalman_core.py)."""
    S = Pp[0, 0] + r
    ne = ze - xp[0, 0]
    nn = zn - xp[1, 0]
    for i in range(order):
        k = Pp[i, 0] / S
        x[0, i] = xp[0, i] + k * ne
        x[1, i] = xp[1, i] + k * nn
        for j in range(i, order):
            v = Pp[i, j] - Pp[i, 0] * Pp[j, 0] / S
            P[i, j] = v
            P[j, i] = v
    return (ne * ne + nn * nn) / S, S


@nb.njit(**_INLINE)
def _copy_state(order, xs, Ps, xd, Pd):
    for i in range(order):
        xd[0, i] = xs[0, i]
        xd[1, i] = xs[1, i]
        for j in range(order):
            Pd[i, j] = Ps[i, j]


# ---- the workspace: every small array the per-track functions use, allocated once per block ----------
# Five arrays (so a call passes ~35 scalars, not ~240 as a tuple of 34 named arrays did): slots of
# (order, order) matrices, (2, order) states, (order,) vectors, the Gauss-Jordan work, and ints.
# Nested functions use disjoint slots (R*: _restart, I*: _info_start / _info_predict).
(_F, _QU, _T, _P, _PP, _PC, _PI, _C, _D, _RF, _RQU, _RT, _RPP, _RP, _IF, _IQU, _IA, _IM, _IMI, _IT,
 _IY) = range(21)
(_X, _XP, _XC, _DX, _RX, _RXP) = range(6)
(_IYE, _IYN, _IV) = range(3)


@nb.njit(**_SEQ)
def _work(order, max_rej):
    """The workspace of one block: (mats, states, vectors, W, ints); ints = rej[max_rej], rows[order], count."""
    return (np.zeros((21, order, order)), np.zeros((6, 2, order)), np.zeros((3, order)),
            np.zeros((MAX_ORDER, 2 * MAX_ORDER)), np.zeros(max(max_rej, 1) + order + 1, dtype=np.int64))


@nb.njit(**_SEQ)
def _inverse(n, A, out, W):
    """out = A^-1 for n <= 3 (Gauss-Jordan, partial pivoting, W work); False if A is numerically singular."""
    scale = 0.0
    for i in range(n):
        for j in range(n):
            W[i, j] = A[i, j]
            W[i, n + j] = 1.0 if i == j else 0.0
            scale = max(scale, abs(A[i, j]))
    if not scale > 0.0:
        return False
    for col in range(n):
        piv = col
        for i in range(col + 1, n):
            if abs(W[i, col]) > abs(W[piv, col]):
                piv = i
        if not abs(W[piv, col]) > 1e-13 * scale:
            return False
        if piv != col:
            for j in range(2 * n):
                tmp = W[col, j]
                W[col, j] = W[piv, j]
                W[piv, j] = tmp
        d = W[col, col]
        for j in range(2 * n):
            W[col, j] /= d
        for i in range(n):
            if i != col:
                f = W[i, col]
                if f != 0.0:
                    for j in range(2 * n):
                        W[i, j] -= f * W[col, j]
    for i in range(n):
        for j in range(n):
            out[i, j] = W[i, n + j]
    return True


@nb.njit(**_SEQ)
def _smooth_track(t, q, order, flag, X, P, wk):
    """RTS backward pass over one track's X, P (filtered -> smoothed, in place), separately on
    each stretch that starts at the track's first fix or at a reset."""
    mats, st, _, W, _ = wk
    F, Qu, Pp, Pi, T, C, D = mats[_F], mats[_QU], mats[_PP], mats[_PI], mats[_T], mats[_C], mats[_D]
    xp, dx = st[_XP], st[_DX]
    for k in range(t.shape[0] - 2, -1, -1):
        if flag[k + 1] == RESET:
            continue  # k ends a stretch: its filtered state is its smoothed state
        chain_transition(order, t[k + 1] - t[k], F, Qu)
        _predict(order, F, Qu, q, X[k], P[k], xp, Pp, T)
        if not _inverse(order, Pp, Pi, W):
            continue  # cannot happen for q > 0 or r > 0; keep the filtered state
        _product(order, T, Pi, C, True, False)   # C = P F^T Pp^-1; T holds F P, so P F^T = T^T
        for ax in range(2):
            for i in range(order):
                dx[ax, i] = X[k + 1, ax, i] - xp[ax, i]
        for ax in range(2):
            for i in range(order):
                s = 0.0
                for j in range(order):
                    s += C[i, j] * dx[ax, j]
                X[k, ax, i] += s
        for i in range(order):                   # P <- P + C (Ps(k+1) - Pp) C^T
            for j in range(order):
                D[i, j] = P[k + 1, i, j] - Pp[i, j]
        _congruence(order, C, D, T, P[k], 1.0, P[k])


@nb.njit(**_SEQ)
def _reject(k, t, ze, zn, w, c, qm, order, gate, x, P, x_coast, P_coast, wk):
    """Fix k is rejected: add it to the run of rejections (the workspace's rej, count); if the
    run is full and its fixes agree (:func:`_restart`), x, P <- the restart state and RESET, else
    x, P <- the coasting state and OUTLIER."""
    ints = wk[4]
    max_rej = ints.shape[0] - order - 1
    rej = ints[:max_rej]
    count = ints[max_rej + order:]
    if count[0] == max_rej:
        for j in range(max_rej - 1):
            rej[j] = rej[j + 1]
        count[0] -= 1
    rej[count[0]] = k
    count[0] += 1
    if count[0] == max_rej and _restart(t, ze, zn, w, c, rej, max_rej, qm, order, gate, x, P, wk):
        count[0] = 0
        return RESET
    _copy_state(order, x_coast, P_coast, x, P)
    return OUTLIER


@nb.njit(**_SEQ)
def _after_reset(store, t, ze, zn, w, c, q, gate, order, x, P, X, Pout, flag, wk):
    """A restart at the last fix of the rejection run: the run's earlier fixes were not outliers but
    the start of the new stretch, and so are the rejected fixes just before the run that lie inside
    the gate of the restart state predicted back to them (walking back, up to the first that does
    not).  They are flagged RESET and, with ``store``, get that back-predicted state instead of the
    coasting state of the old stretch; the prediction goes back one row at a time,
    x_(k-1) = F(-d) x_k, P_(k-1) = F(-d) (P_k + q Qu(d)) F(-d)^T, d = t_k - t_(k-1)."""
    mats, st, _, _, ints = wk
    max_rej = ints.shape[0] - order - 1
    rej = ints[:max_rej]
    F, Qu, T, Pb, Pp, xb, xp = mats[_RF], mats[_RQU], mats[_RT], mats[_RP], mats[_RPP], st[_RX], st[_RXP]
    k = rej[max_rej - 1]
    _copy_state(order, x, P, xb, Pb)
    m = max_rej - 1
    while True:
        if m > 0:                 # the run's own fixes
            m -= 1
            j = rej[m]
            inside_run = True
        else:                     # the rejected fixes just before it
            j = k - 1
            if j < 1 or flag[j] != OUTLIER:
                break
            inside_run = False
        while k > j:
            d = t[k] - t[k - 1]
            chain_transition(order, d, F, Qu)
            for a in range(order):
                for b in range(order):
                    Pb[a, b] += q * Qu[a, b]
            chain_transition(order, -d, F, T)
            _predict(order, F, Qu, 0.0, xb, Pb, xp, Pp, T)
            _copy_state(order, xp, Pp, xb, Pb)
            k -= 1
        if not inside_run:
            ne = ze[j] - xb[0, 0]
            nn = zn[j] - xb[1, 0]
            if (ne * ne + nn * nn) / (Pb[0, 0] + c * w[j]) > gate:
                break
        flag[j] = RESET
        if store:
            _copy_state(order, xb, Pb, X[j], Pout[j])


@nb.njit(**_SEQ)
def _filter_track(t, ze, zn, w, c, q, order, prior, gate, store, X, P, nis, flag, stats, wk):
    """The gated filter over one track's rows (see filter_tracks), fix variances c w[k]; stats <-
    (loglik, updates, outliers, resets, NIS sum of the updates and manoeuvres, manoeuvres).

    A fix that fails the gate but passes it under the manoeuvre density qm is a candidate: the
    filter goes on from its manoeuvre update, and the next fix decides: inside the (nominal) gate
    of that track, the candidate is a manoeuvre; otherwise it was an outlier and the filter goes
    back to coasting through it.  A candidate at a track's last fix is taken as a manoeuvre."""
    n = t.shape[0]
    mats, st, _, _, ints = wk
    F, Qu, T, Pc, Pp, P_coast = mats[_F], mats[_QU], mats[_T], mats[_P], mats[_PP], mats[_PC]
    x, xp, x_coast = st[_X], st[_XP], st[_XC]
    count = ints[ints.shape[0] - 1:]
    count[0] = 0
    loglik = 0.0
    qm = MANOEUVRE_FACTOR * q
    pending = False               # fix k - 1 is a manoeuvre candidate
    cand_e = cand_ll = 0.0        # its nominal NIS and its log-likelihood as a manoeuvre
    for i in range(order):
        x[0, i] = 0.0
        x[1, i] = 0.0
        for j in range(order):
            Pc[i, j] = 0.0
    x[0, 0] = ze[0]
    x[1, 0] = zn[0]
    Pc[0, 0] = c * w[0]
    for i in range(1, order):
        Pc[i, i] = prior[i]
    nis[0] = np.nan
    flag[0] = INIT
    if store:
        _copy_state(order, x, Pc, X[0], P[0])
    for k in range(1, n):
        rk = c * w[k]
        chain_transition(order, t[k] - t[k - 1], F, Qu)
        _predict(order, F, Qu, q, x, Pc, xp, Pp, T)
        S = Pp[0, 0] + rk
        ne = ze[k] - xp[0, 0]
        nn = zn[k] - xp[1, 0]
        e = (ne * ne + nn * nn) / S
        if pending:
            pending = False
            if e <= gate:                 # fix k confirms the manoeuvre at k - 1
                loglik += cand_ll
                count[0] = 0
            else:                         # it does not: k - 1 was an outlier
                nis[k - 1] = cand_e
                flag[k - 1] = _reject(k - 1, t, ze, zn, w, c, qm, order, gate, x, Pc, x_coast, P_coast, wk)
                if flag[k - 1] == RESET:
                    _after_reset(store, t, ze, zn, w, c, q, gate, order, x, Pc, X, P, flag, wk)
                if store:
                    _copy_state(order, x, Pc, X[k - 1], P[k - 1])
                _predict(order, F, Qu, q, x, Pc, xp, Pp, T)
                S = Pp[0, 0] + rk
                ne = ze[k] - xp[0, 0]
                nn = zn[k] - xp[1, 0]
                e = (ne * ne + nn * nn) / S
        nis[k] = e
        if e <= gate:
            count[0] = 0
            e, S = _update(order, xp, Pp, rk, ze[k], zn[k], x, Pc)
            flag[k] = UPDATE
            loglik -= 0.5 * (e + 2.0 * math.log(S) + 2.0 * _LOG2PI)
        else:
            _copy_state(order, xp, Pp, x_coast, P_coast)
            for i in range(order):        # the manoeuvre hypothesis: the prediction with density qm
                for j in range(order):
                    Pp[i, j] += (qm - q) * Qu[i, j]
            Sm = Pp[0, 0] + rk
            em = (ne * ne + nn * nn) / Sm
            if em <= gate:                # a candidate: the next fix decides
                em, Sm = _update(order, xp, Pp, rk, ze[k], zn[k], x, Pc)
                flag[k] = MANOEUVRE
                nis[k] = em
                pending = True
                cand_e, cand_ll = e, -0.5 * (em + 2.0 * math.log(Sm) + 2.0 * _LOG2PI)
            else:
                flag[k] = _reject(k, t, ze, zn, w, c, qm, order, gate, x, Pc, x_coast, P_coast, wk)
                if flag[k] == RESET:
                    _after_reset(store, t, ze, zn, w, c, q, gate, order, x, Pc, X, P, flag, wk)
        if store:
            _copy_state(order, x, Pc, X[k], P[k])
    if pending:                           # a candidate at the last fix is a manoeuvre
        loglik += cand_ll
    stats[0] = loglik
    for i in range(1, 6):
        stats[i] = 0.0
    for k in range(1, n):                 # counts and NIS sum from the flags
        f = flag[k]
        if f == UPDATE or f == MANOEUVRE:
            stats[4] += nis[k]
        if f == UPDATE:
            stats[1] += 1.0
        elif f == OUTLIER:
            stats[2] += 1.0
        elif f == RESET and flag[k - 1] != RESET:  # a restart run is one reset
            stats[3] += 1.0
        elif f == MANOEUVRE:
            stats[5] += 1.0


# ---- noise estimation: the conditional (diffuse-start) log-likelihood ---------------------------------

@nb.njit(**_INLINE)
def _info_predict(order, dt, q, Y, ye, yn, wk):
    """Information-form prediction over dt of a possibly singular information matrix Y:
    Y <- A (I + Q A)^-1, y <- (I + A Q)^-1 F^-T y with A = F^-T Y F^-1 (exact also for singular
    Y or Q, since I + Q A is invertible for PSD Q, A)."""
    if dt == 0.0:
        return True
    mats, _, vec, W, _ = wk
    F, Qu, A, M, Mi, tmp, v = mats[_IF], mats[_IQU], mats[_IA], mats[_IM], mats[_IMI], mats[_IT], vec[_IV]
    chain_transition(order, -dt, F, Qu)   # F(-dt) = F(dt)^-1; Qu of -dt is not used
    chain_transition(order, dt, M, Qu)    # only Qu(dt) is kept (M is overwritten below)
    _product(order, Y, F, tmp, False, False)   # A = Fi^T Y Fi
    _product(order, F, tmp, A, True, False)
    for i in range(order):                # M = I + Q A
        for j in range(order):
            s = 1.0 if i == j else 0.0
            for m in range(order):
                s += q * Qu[i, m] * A[m, j]
            M[i, j] = s
    if not _inverse(order, M, Mi, W):
        return False
    _product(order, A, Mi, tmp, False, False)  # Y = A M^-1 (symmetric)
    for i in range(order):
        for j in range(order):
            Y[i, j] = 0.5 * (tmp[i, j] + tmp[j, i])
    for ax in range(2):                   # y = M^-T Fi^T y
        y = ye if ax == 0 else yn
        for i in range(order):
            s = 0.0
            for m in range(order):
                s += F[m, i] * y[m]
            v[i] = s
        for i in range(order):
            s = 0.0
            for m in range(order):
                s += Mi[m, i] * v[m]
            y[i] = s
    return True


@nb.njit(**_INLINE)
def _info_start(t, ze, zn, w, c, rows, n_rows, q, order, x, P, wk):
    """The exact state after the fixes ``rows[:n_rows]`` from zero information (a diffuse start):
    information-form predictions between them (density q), x, P <- the state at the last one.
    False if their information is singular (fewer than ``order`` distinct times) or numerically lost."""
    distinct = 1
    for j in range(1, n_rows):
        if t[rows[j]] != t[rows[j - 1]]:
            distinct += 1
    if distinct < order:  # a chain of order r needs fixes at r distinct times
        return False
    mats, _, vec, W, _ = wk
    Y, ye, yn = mats[_IY], vec[_IYE], vec[_IYN]
    for i in range(order):
        ye[i] = 0.0
        yn[i] = 0.0
        for j in range(order):
            Y[i, j] = 0.0
    for j in range(n_rows):
        k = rows[j]
        if j > 0 and not _info_predict(order, t[k] - t[rows[j - 1]], q, Y, ye, yn, wk):
            return False
        rk = c * w[k]
        Y[0, 0] += 1.0 / rk
        ye[0] += ze[k] / rk
        yn[0] += zn[k] / rk
    if not _inverse(order, Y, P, W):
        return False
    for i in range(order):
        for j in range(i + 1, order):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v
    for i in range(order):
        se = 0.0
        sn = 0.0
        for j in range(order):
            se += P[i, j] * ye[j]
            sn += P[i, j] * yn[j]
        x[0, i] = se
        x[1, i] = sn
    return True


@nb.njit(**_SEQ)
def _restart(t, ze, zn, w, c, rej, nrej, qm, order, gate, x, P, wk):
    """The restart test of a run of ``nrej`` rejected fixes ``rej``: a diffuse start on the first
    ``order`` of them under the manoeuvre density ``qm``, then each further one must pass the NIS
    gate against the prediction from those before it.  If all do, x, P <- the state at the last
    one and True (the track restarts there); the fixes are left alone otherwise."""
    mats, st, _, _, _ = wk
    xs, Ps = st[_RX], mats[_RP]
    if not _info_start(t, ze, zn, w, c, rej, order, qm, order, xs, Ps, wk):
        return False
    F, Qu, T, xp, Pp = mats[_RF], mats[_RQU], mats[_RT], st[_RXP], mats[_RPP]
    for j in range(order, nrej):
        k = rej[j]
        chain_transition(order, t[k] - t[rej[j - 1]], F, Qu)
        _predict(order, F, Qu, qm, xs, Ps, xp, Pp, T)
        S = Pp[0, 0] + c * w[k]
        ne = ze[k] - xp[0, 0]
        nn = zn[k] - xp[1, 0]
        if (ne * ne + nn * nn) / S > gate:
            return False
        _update(order, xp, Pp, c * w[k], ze[k], zn[k], xs, Ps)
    _copy_state(order, xs, Ps, x, P)
    return True


@nb.njit(**_INLINE)
def _diffuse_start(k, t, ze, zn, w, mask, c, q, order, x, P, wk):
    """Collect the next ``order`` accepted fixes from row k on (a RESTART begins the collection
    again) and start from them (:func:`_info_start`).  Returns the row after the last of them, or
    -1 if the rows run out first."""
    n = t.shape[0]
    ints = wk[4]
    rows = ints[ints.shape[0] - order - 1:ints.shape[0] - 1]
    count = 0
    while k < n:
        code = mask[k]
        if code != SKIP:
            if code == RESTART:
                count = 0
            rows[count] = k
            count += 1
            if count == order:
                if _info_start(t, ze, zn, w, c, rows, order, q, order, x, P, wk):
                    return k + 1
                for j in range(order - 1):  # singular (equal times): slide the window on
                    rows[j] = rows[j + 1]
                count -= 1
        k += 1
    return -1


@nb.njit(**_INLINE)
def _track_loglik(t, ze, zn, w, mask, c, q, order, out, wk):
    """out <- (E, L, N): sum of NIS, sum of log det S and number of scalar innovations of the fixes
    ``mask`` accepts, conditional on the first ``order`` accepted fixes of each stretch (a stretch
    starts at row 0 and at each RESTART)."""
    mats, st, _, _, _ = wk
    F, Qu, tmp, P, Ps, Pp = mats[_F], mats[_QU], mats[_T], mats[_P], mats[_PC], mats[_PP]
    x, xs, xp = st[_X], st[_XC], st[_XP]
    E = 0.0
    L = 0.0
    N = 0.0
    n = t.shape[0]
    k = 0
    while k < n:
        k = _diffuse_start(k, t, ze, zn, w, mask, c, q, order, xs, Ps, wk)
        if k < 0:
            break
        _copy_state(order, xs, Ps, x, P)
        t_last = t[k - 1]
        while k < n:           # the hot loop: no calls that are not inlined
            code = mask[k]
            if code == RESTART:
                break
            if code != SKIP:
                chain_transition(order, t[k] - t_last, F, Qu)
                _predict(order, F, Qu, q, x, P, xp, Pp, tmp)
                e, S = _update(order, xp, Pp, c * w[k], ze[k], zn[k], x, P)
                E += e
                L += 2.0 * math.log(S)
                N += 2.0
                t_last = t[k]
            k += 1
    out[0] = E
    out[1] = L
    out[2] = N


# ---- the parallel kernels, compiled once per model order ------------------------------------------------

_BLOCKS = 256   # tracks are split into at most this many blocks; each allocates one workspace


def _make_kernels(order: int):
    """The parallel kernels with ``order`` a compile-time constant (the small per-fix loops unroll;
    a runtime order made them 3x slower).  numba caches each closure per constant."""

    @nb.njit(**_PAR)
    def filter_kernel(offsets, t, ze, zn, w, c, q, prior, gate, max_rej, store, smooth, X, P, nis, flag, stats):
        B = offsets.shape[0] - 1
        nblk = min(B, _BLOCKS)
        for blk in nb.prange(nblk):
            wk = _work(order, max_rej)
            for b in range(blk * B // nblk, (blk + 1) * B // nblk):
                a0 = offsets[b]
                b0 = offsets[b + 1]
                if b0 <= a0:
                    continue
                _filter_track(t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], c[b], q[b], order, prior, gate, store,
                              X[a0:b0], P[a0:b0], nis[a0:b0], flag[a0:b0], stats[b], wk)
                if smooth and store:
                    _smooth_track(t[a0:b0], q[b], order, flag[a0:b0], X[a0:b0], P[a0:b0], wk)

    @nb.njit(**_PAR)
    def loglik_kernel(offsets, active, t, ze, zn, w, mask, c, q, out):
        B = offsets.shape[0] - 1
        nblk = min(B, _BLOCKS)
        for blk in nb.prange(nblk):
            wk = _work(order, 1)
            for b in range(blk * B // nblk, (blk + 1) * B // nblk):
                if not active[b]:
                    continue
                a0 = offsets[b]
                b0 = offsets[b + 1]
                _track_loglik(t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], mask[a0:b0], c[b], q[b], order, out[b], wk)

    return filter_kernel, loglik_kernel


_KERNELS = {}


def _kernels(order: int):
    if order not in _KERNELS:
        if order not in (2, 3):
            raise ValueError(f"order: the engine runs integrator chains of order 2 or 3, got {order}")
        _KERNELS[order] = _make_kernels(order)
    return _KERNELS[order]


def filter_tracks(offsets, t, ze, zn, w, c, q, order, prior, gate, max_rej, store, smooth, X, P, nis, flag, stats):
    """Gated Kalman filter (and RTS smoother) of every track; fills the outputs in place.

    offsets  (B+1,) track b is rows offsets[b]:offsets[b+1]; rows in time order
    t, ze, zn  (N,) seconds, east and north metres of the fixes
    w, c     fix variance of row k in track b is r = c[b] w[k] (m^2 per axis)
    q        (B,) process-noise density of each track (m^2/s^3 for order 2)
    order    states per axis: 2 (cv) or 3 (ca)
    prior    (order,) prior variances of the derivatives at a track's first fix (entry 0 unused)
    gate     NIS threshold (inf: no gating): a fix above it is tried against the manoeuvre
             hypothesis (density MANOEUVRE_FACTOR q) and else rejected; ``max_rej`` rejections in a
             row restart the track if they agree with each other (:func:`_restart`)
    X, P     (N, 2, order), (N, order, order): the states, written if ``store`` (else left as they are)
    smooth   replace the stored filtered states by RTS-smoothed ones
    nis, flag (N,)  NIS of each fix (NaN at a track's first fix), index into FLAGS
    stats    (B, 6)  loglik, updates, outliers, resets, NIS sum of the updates and manoeuvres, manoeuvres
    """
    _kernels(order)[0](offsets, t, ze, zn, w, c, q, prior, gate, max_rej, store, smooth, X, P, nis, flag, stats)


def loglik_tracks(offsets, active, t, ze, zn, w, mask, c, q, order, out):
    """(E, L, N) of :func:`_track_loglik` for every track b with active[b] (out (B, 3)); track b
    uses fix variances c[b] w[k] and process-noise density q[b]."""
    _kernels(order)[1](offsets, active, t, ze, zn, w, mask, c, q, out)


@nb.njit(**_SEQ)
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


@nb.njit(**_PAR)
def moment_guess(offsets, t, ze, zn, w, mask, out):
    """out (B, 3) <- :func:`_track_moments` of every track."""
    B = offsets.shape[0] - 1
    for b in nb.prange(B):
        a0 = offsets[b]
        b0 = offsets[b + 1]
        _track_moments(t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], mask[a0:b0], out[b])
