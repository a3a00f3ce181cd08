"""The gated filter of one track on the integrator chains, and its RTS pass: the per-track steps of
the tracking engine (:mod:`._engine` runs them over all tracks in one compiled call).

The filter (the two-level NIS gate with a one-fix lookahead, restarts, segments
after a gap) is the one of :mod:`._gated`, specialised to the integrator chains
of :mod:`._chain`, and equal to that per-track reference to rounding (tests).
It reads and writes one track's state row (:mod:`._state`) and the output rows
of its fixes; rows of an earlier call that a decision revises go to the
revision arrays (:class:`._engine.Revisions`).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ._chain import (INLINE, LOG2PI, M_C, M_D, M_F, M_P, M_PC, M_PI, M_PP, M_QU, M_RF, M_RP, M_RPP, M_RQU, M_RT,
                     M_RUN, M_T, M_UA, M_UT, S_DX, S_RUN, S_RX, S_RXP, S_X, S_XC, S_XP, SEQ, V_UK, congruence,
                     copy_state, info_start, innovation, inverse, predict, product, transition, update)
from ._state import (ST_BEFORE, ST_CAND_E, ST_CAND_EM, ST_CAND_LL, ST_FIXES, ST_LOGLIK, ST_MANOEUVRES, ST_NIS_SUM,
                     ST_OUTLIERS, ST_PENDING, ST_RESETS, ST_STREAK, ST_T_LAST, ST_UPDATES, ST_WINDOW, STREAK_CAP,
                     load_block, save_block, state_layout)

__all__ = ["FLAGS", "INIT", "UPDATE", "OUTLIER", "PREDICTED", "RESET", "MANOEUVRE", "MANOEUVRE_FACTOR",
           "advance_track", "smooth_track"]

#: Per-point flags of a tracking result (the output's ``flag`` column), by index.
FLAGS = ("update", "outlier", "predicted", "reset", "init", "manoeuvre")
UPDATE, OUTLIER, PREDICTED, RESET, INIT, MANOEUVRE = range(6)
#: Process noise of the manoeuvre hypothesis, as a multiple of the model's density q.
MANOEUVRE_FACTOR = 10.0


@nb.njit(**INLINE)
def _put_state(n, j, f, e, x, P, store, X, Pout, flag, nis, rev_n, rev_flag, rev_nis, rev_X, rev_P):
    """Row j of the call (j < 0: the fix -j rows before the call's first, a revision) <- flag f,
    NIS e (NaN: unchanged) and, with ``store``, the state x, P."""
    if j >= 0:
        flag[j] = f
        if not np.isnan(e):
            nis[j] = e
        if store:
            copy_state(n, x, P, X[j], Pout[j])
        return
    d = -j - 1
    if d >= rev_flag.shape[0]:
        return   # no room: the caller asked for no revisions
    rev_flag[d] = f
    if not np.isnan(e):
        rev_nis[d] = e
    if store:
        copy_state(n, x, P, rev_X[d], rev_P[d])
    if d + 1 > rev_n[0]:
        rev_n[0] = d + 1


@nb.njit(**INLINE)
def _init(order, n, ze, zn, r, sb2, prior, x, P):
    """The state at a track's (or segment's) first fix: flat prior on the position, the slow fix error b
    at its own prior N(0, sb2) (so p = z - b - v: variance r + sb2, covariance -sb2 with b), the other
    derivatives 0 with variances ``prior[1:]``."""
    for i in range(n):
        x[0, i] = 0.0
        x[1, i] = 0.0
        for j in range(n):
            P[i, j] = 0.0
    x[0, 0] = ze
    x[1, 0] = zn
    P[0, 0] = r + sb2
    for i in range(1, order):
        P[i, i] = prior[i]
    P[order, order] = sb2
    P[0, order] = -sb2
    P[order, 0] = -sb2


@nb.njit(**SEQ)
def _restart(bt, bze, bzn, bw, L, c, qm, sb2, tau, order, nrej, gate, x, P, wk):
    """The restart test of the last ``nrej`` rejected fixes (the streak's entries L - nrej .. L - 1):
    a diffuse start on the first ``order`` of them under the manoeuvre density ``qm`` (the slow fix
    error from its own prior), then each further one must pass the NIS gate against the prediction
    from those before it.  If all do, x, P <- the state at the last one and True (the track restarts
    there); the state at each fix of the run from the ``order``-th on is left in the workspace's run
    slots (M_RUN + j, S_RUN + j for the run's fix j), for :func:`_after_reset`."""
    n = order + 1
    mats, st, vec, _, rows = wk
    for j in range(nrej):
        rows[j] = L - nrej + j
    xs, Ps = st[S_RX], mats[M_RP]
    ne = n if sb2 > 0.0 else order      # no slow error (sb2 = 0): b stays 0, the start is the chain's
    if not info_start(bt, bze, bzn, bw, c, rows, order, qm, order, ne, tau, sb2, xs, Ps, wk):
        return False
    if ne < n:
        for i in range(n):
            Ps[order, i] = 0.0
            Ps[i, order] = 0.0
        xs[0, order] = 0.0
        xs[1, order] = 0.0
    copy_state(n, xs, Ps, st[S_RUN + order - 1], mats[M_RUN + order - 1])
    F, Qu, T, xp, Pp = mats[M_RF], mats[M_RQU], mats[M_RT], st[S_RXP], mats[M_RPP]
    for j in range(order, nrej):
        k = rows[j]
        qb = sb2 * transition(order, n, bt[k] - bt[k - 1], tau, F, Qu)
        predict(n, F, Qu, qm, qb, xs, Ps, xp, Pp, T)
        e, _ = innovation(n, order, xp, Pp, c * bw[k], bze[k], bzn[k])
        if e > gate:
            return False
        update(n, order, xp, Pp, c * bw[k], bze[k], bzn[k], xs, Ps, mats[M_UA], mats[M_UT], vec[V_UK])
        copy_state(n, xs, Ps, st[S_RUN + j], mats[M_RUN + j])
    copy_state(n, xs, Ps, x, P)
    return True


@nb.njit(**SEQ)
def _after_reset(k, L, streak, nrej, bt, bze, bzn, bw, c, q, sb2, tau, gate, order, store, X, Pout, flag,
                 nis, rev_n, rev_flag, rev_nis, rev_X, rev_P, wk):
    """A restart at row k, the last of the streak's L kept entries: the run's earlier fixes were not
    outliers but the start of the new stretch, and so are the rejected fixes just before the run
    that lie inside the gate of the new stretch's state predicted back to them (walking back, up to
    the first that does not, or the first the state keeps).  They are flagged RESET and, with
    ``store``, get the new stretch's state instead of the coasting state of the old one: at the run's
    fixes from the ``order``-th on, the restart test's state there (the filter started at the run's
    first fix, :func:`_restart`); before it, that state predicted back one fix at a time,
    x_(k-1) = F(-d) x_k, P_(k-1) = F(-d) (P_k + Q(d)) F(-d)^T, d = t_k - t_(k-1), and updated with the
    fix there when it is one before the run (the new stretch taken back to it, a backward filter).
    Returns (rows relabelled, whether they reach back to the fix before the run of rejections)."""
    n = order + 1
    mats, st, vec, _, _ = wk
    F, Qu, T, Pb, Pp, xb, xp = mats[M_RF], mats[M_RQU], mats[M_RT], mats[M_RP], mats[M_RPP], st[S_RX], st[S_RXP]
    relabelled = 0
    w0 = L - nrej                 # the run's first fix
    for i in range(L - 2, w0 + order - 2, -1):   # the run's fixes with a state of the new stretch's filter
        _put_state(n, k - (L - 1 - i), RESET, np.nan, st[S_RUN + i - w0], mats[M_RUN + i - w0], store, X, Pout,
                   flag, nis, rev_n, rev_flag, rev_nis, rev_X, rev_P)
        relabelled += 1
    copy_state(n, st[S_RUN + order - 1], mats[M_RUN + order - 1], xb, Pb)
    i = w0 + order - 1
    while i > 0:
        d = bt[i] - bt[i - 1]
        qb = sb2 * transition(order, n, d, tau, F, Qu)
        for a in range(n):
            for b in range(n):
                Pb[a, b] += q * Qu[a, b]
        Pb[n - 1, n - 1] += qb
        transition(order, n, -d, tau, F, T)
        predict(n, F, Qu, 0.0, 0.0, xb, Pb, xp, Pp, T)
        copy_state(n, xp, Pp, xb, Pb)
        i -= 1
        if i < L - nrej:          # before the run: inside the gate of the back prediction? then its fix joins
            e, _ = innovation(n, order, xb, Pb, c * bw[i], bze[i], bzn[i])
            if e > gate:
                return relabelled, False
            update(n, order, xb, Pb, c * bw[i], bze[i], bzn[i], xp, Pp, mats[M_UA], mats[M_UT], vec[V_UK])
            copy_state(n, xp, Pp, xb, Pb)
        _put_state(n, k - (L - 1 - i), RESET, np.nan, xb, Pb, store, X, Pout, flag, nis,
                   rev_n, rev_flag, rev_nis, rev_X, rev_P)
        relabelled += 1
    return relabelled, streak == L


@nb.njit(**SEQ)
def _reject(k, tk, zek, znk, wk_, st, streak0, c, q, sb2, tau, order, max_rej, gate, store, x, P, x_coast,
            P_coast, X, Pout, flag, nis, rev_n, rev_flag, rev_nis, rev_X, rev_P, wk):
    """Row k (time tk, fix (zek, znk), unit variance wk_) is rejected: it joins the streak of
    rejected fixes and the restart test's window; if the window is full and its fixes agree
    (:func:`_restart`), x, P <- the restart state, the run is relabelled (:func:`_after_reset`)
    and RESET is returned; else x, P <- the coasting state and OUTLIER."""
    bt = st[streak0:streak0 + STREAK_CAP]
    bze = st[streak0 + STREAK_CAP:streak0 + 2 * STREAK_CAP]
    bzn = st[streak0 + 2 * STREAK_CAP:streak0 + 3 * STREAK_CAP]
    bw = st[streak0 + 3 * STREAK_CAP:streak0 + 4 * STREAK_CAP]
    streak = int(st[ST_STREAK])
    L = min(streak, STREAK_CAP)
    if L == STREAK_CAP:                     # keep the last STREAK_CAP
        for j in range(STREAK_CAP - 1):
            bt[j] = bt[j + 1]
            bze[j] = bze[j + 1]
            bzn[j] = bzn[j + 1]
            bw[j] = bw[j + 1]
        L -= 1
    bt[L] = tk
    bze[L] = zek
    bzn[L] = znk
    bw[L] = wk_
    L += 1
    streak += 1
    st[ST_STREAK] = streak
    st[ST_OUTLIERS] += 1.0
    window = min(int(st[ST_WINDOW]) + 1, max_rej)
    st[ST_WINDOW] = window
    if window == max_rej and _restart(bt, bze, bzn, bw, L, c, MANOEUVRE_FACTOR * q, sb2, tau, order, max_rej, gate,
                                      x, P, wk):
        relabelled, whole = _after_reset(k, L, streak, max_rej, bt, bze, bzn, bw, c, q, sb2, tau, gate, order, store,
                                         X, Pout, flag, nis, rev_n, rev_flag, rev_nis, rev_X, rev_P, wk)
        st[ST_OUTLIERS] -= 1.0 + relabelled
        if not (whole and st[ST_BEFORE] == RESET):   # a restart run is one reset (it may join one before it)
            st[ST_RESETS] += 1.0
        _end_streak(st, RESET)
        return RESET
    copy_state(order + 1, x_coast, P_coast, x, P)
    return OUTLIER


@nb.njit(**INLINE)
def _end_streak(st, f):
    """A fix flagged f that is not rejected ends the run of rejections."""
    st[ST_WINDOW] = 0.0
    st[ST_STREAK] = 0.0
    st[ST_BEFORE] = f


@nb.njit(**INLINE)
def _confirm(st):
    """The pending candidate is a manoeuvre: its log-likelihood, NIS and count join the counters."""
    st[ST_LOGLIK] += st[ST_CAND_LL]
    st[ST_NIS_SUM] += st[ST_CAND_EM]
    st[ST_MANOEUVRES] += 1.0
    _end_streak(st, MANOEUVRE)


@nb.njit(**SEQ)
def advance_track(st, t, ze, zn, w, c, q, sb2, tau, order, prior, gate, max_rej, max_gap, store, X, P, nis, flag,
                  stats, rev_n, rev_flag, rev_nis, rev_X, rev_P, wk):
    """The gated filter over one track's new rows from its state ``st`` (updated in place), fix
    variances c w[k], motion density q, the fix error's slow part of stationary variance sb2 and time
    constant tau; stats <- (loglik, updates, outliers, resets, NIS sum of the updates and
    manoeuvres, manoeuvres) of all its fixes so far, a pending candidate counted as a manoeuvre.

    A fix that fails the gate but passes it under the manoeuvre density qm is a candidate: the
    filter goes on from its manoeuvre update, and the next fix decides: inside the (nominal) gate
    of that track, the candidate is a manoeuvre; otherwise it was an outlier and the filter goes
    back to coasting through it.  A candidate at the last fix so far (or of a segment) counts as a
    manoeuvre.  A fix more than ``max_gap`` seconds after the last starts a new segment: it
    initialises the filter again (flag INIT, no NIS)."""
    n_rows = t.shape[0]
    if n_rows == 0 and st[ST_FIXES] == 0.0:
        return   # an empty track without fixes: nothing to report
    n = order + 1
    hb = order
    mats, sts, vec, _, _ = wk
    F, Qu, T, Pc, Pp, P_coast = mats[M_F], mats[M_QU], mats[M_T], mats[M_P], mats[M_PP], mats[M_PC]
    UA, UT, uk = mats[M_UA], mats[M_UT], vec[V_UK]
    x, xp, x_coast = sts[S_X], sts[S_XP], sts[S_XC]
    x0, p0, xc0, pc0, cand0, streak0, _ = state_layout(n)
    qm = MANOEUVRE_FACTOR * q
    rev_n[0] = 0
    for d in range(rev_nis.shape[0]):
        rev_nis[d] = np.nan
    if st[ST_FIXES] > 0.0:
        load_block(n, st, x0, p0, x, Pc)
        load_block(n, st, xc0, pc0, x_coast, P_coast)
    pending = st[ST_PENDING] != 0.0
    t_last = st[ST_T_LAST]
    for k in range(n_rows):
        rk = c * w[k]
        if st[ST_FIXES] == 0.0 or t[k] - t_last > max_gap:   # a track's or a segment's first fix
            if pending:
                _confirm(st)
                pending = False
            _init(order, n, ze[k], zn[k], rk, sb2, prior, x, Pc)
            nis[k] = np.nan
            flag[k] = INIT
            _end_streak(st, INIT)
            if store:
                copy_state(n, x, Pc, X[k], P[k])
            t_last = t[k]
            st[ST_FIXES] += 1.0
            continue
        qb = sb2 * transition(order, n, t[k] - t_last, tau, F, Qu)
        predict(n, F, Qu, q, qb, x, Pc, xp, Pp, T)
        e, S = innovation(n, hb, xp, Pp, rk, ze[k], zn[k])
        if pending:
            pending = False
            if e <= gate:                 # fix k confirms the manoeuvre at k - 1
                _confirm(st)
            else:                         # it does not: k - 1 was an outlier
                f = _reject(k - 1, t_last, st[cand0], st[cand0 + 1], st[cand0 + 2], st, streak0, c, q, sb2, tau,
                            order, max_rej, gate, store, x, Pc, x_coast, P_coast, X, P, flag, nis,
                            rev_n, rev_flag, rev_nis, rev_X, rev_P, wk)
                _put_state(n, k - 1, f, st[ST_CAND_E], x, Pc, store, X, P, flag, nis,
                           rev_n, rev_flag, rev_nis, rev_X, rev_P)
                predict(n, F, Qu, q, qb, x, Pc, xp, Pp, T)
                e, S = innovation(n, hb, xp, Pp, rk, ze[k], zn[k])
        nis[k] = e
        if e <= gate:
            e, S = update(n, hb, xp, Pp, rk, ze[k], zn[k], x, Pc, UA, UT, uk)
            flag[k] = UPDATE
            st[ST_LOGLIK] -= 0.5 * (e + 2.0 * math.log(S) + 2.0 * LOG2PI)
            st[ST_NIS_SUM] += nis[k]
            st[ST_UPDATES] += 1.0
            _end_streak(st, UPDATE)
        else:
            copy_state(n, xp, Pp, x_coast, P_coast)
            for i in range(n):            # the manoeuvre hypothesis: the prediction with motion density qm
                for j in range(n):
                    Pp[i, j] += (qm - q) * Qu[i, j]
            em, Sm = innovation(n, hb, xp, Pp, rk, ze[k], zn[k])
            if em > gate:                 # and the sharp manoeuvre: density MANOEUVRE_FACTOR^2 q
                for i in range(n):
                    for j in range(n):
                        Pp[i, j] += (MANOEUVRE_FACTOR * qm - qm) * Qu[i, j]
                em, Sm = innovation(n, hb, xp, Pp, rk, ze[k], zn[k])
            if em <= gate:                # a candidate: the next fix decides
                em, Sm = update(n, hb, xp, Pp, rk, ze[k], zn[k], x, Pc, UA, UT, uk)
                flag[k] = MANOEUVRE
                nis[k] = em
                pending = True
                st[ST_CAND_E] = e
                st[ST_CAND_LL] = -0.5 * (em + 2.0 * math.log(Sm) + 2.0 * LOG2PI)
                st[ST_CAND_EM] = em
                st[cand0] = ze[k]
                st[cand0 + 1] = zn[k]
                st[cand0 + 2] = w[k]
            else:
                flag[k] = _reject(k, t[k], ze[k], zn[k], w[k], st, streak0, c, q, sb2, tau, order, max_rej, gate,
                                  store, x, Pc, x_coast, P_coast, X, P, flag, nis, rev_n, rev_flag, rev_nis, rev_X,
                                  rev_P, wk)
        if store:
            copy_state(n, x, Pc, X[k], P[k])
        t_last = t[k]
        st[ST_FIXES] += 1.0
    st[ST_T_LAST] = t_last
    st[ST_PENDING] = 1.0 if pending else 0.0
    save_block(n, st, x0, p0, x, Pc)
    save_block(n, st, xc0, pc0, x_coast, P_coast)
    stats[0] = st[ST_LOGLIK]
    stats[1] = st[ST_UPDATES]
    stats[2] = st[ST_OUTLIERS]
    stats[3] = st[ST_RESETS]
    stats[4] = st[ST_NIS_SUM]
    stats[5] = st[ST_MANOEUVRES]
    if pending:                           # a candidate at the last fix so far counts as a manoeuvre
        stats[0] += st[ST_CAND_LL]
        stats[4] += st[ST_CAND_EM]
        stats[5] += 1.0


@nb.njit(**SEQ)
def smooth_track(t, ze, zn, w, c, q, sb2, tau, order, gate, flag, X, P, wk):
    """RTS backward pass over one track's X, P (filtered -> smoothed, in place), separately on
    each stretch that starts at a track's or segment's first fix (INIT) or at a reset.  The step to
    a manoeuvre takes the manoeuvre's process noise, as the filter did (its level found again: the
    first of MANOEUVRE_FACTOR q, MANOEUVRE_FACTOR^2 q whose gate the fix passes from X[k], P[k]).

    The backward recursion of :mod:`mptrack._core.rts` written out for the engine's shared covariance of
    two axes (one smoother gain C for both): a documented exception to the one RTS pass, tested
    against it through :func:`._gated.rts_smoother_gated` (tests/tracking/test_tracking_engine.py)."""
    n = order + 1 if sb2 > 0.0 else order   # without a slow error its state is 0 and left out (P would be singular)
    mats, st, _, W, _ = wk
    F, Qu, Pp, Pi, T, C, D = mats[M_F], mats[M_QU], mats[M_PP], mats[M_PI], mats[M_T], mats[M_C], mats[M_D]
    xp, dx = st[S_XP], st[S_DX]
    for k in range(t.shape[0] - 2, -1, -1):
        if flag[k + 1] == RESET or flag[k + 1] == INIT:
            continue  # k ends a stretch: its filtered state is its smoothed state
        qb = sb2 * transition(order, n, t[k + 1] - t[k], tau, F, Qu)
        qk = q
        if flag[k + 1] == MANOEUVRE:
            qk = MANOEUVRE_FACTOR * q
            predict(n, F, Qu, qk, qb, X[k], P[k], xp, Pp, T)
            if innovation(n, order if n > order else -1, xp, Pp, c * w[k + 1], ze[k + 1], zn[k + 1])[0] > gate:
                qk = MANOEUVRE_FACTOR * qk
        predict(n, F, Qu, qk, qb, X[k], P[k], xp, Pp, T)
        if not inverse(n, Pp, Pi, W):
            continue  # cannot happen for q > 0 or r > 0; keep the filtered state
        product(n, T, Pi, C, True, False)   # C = P F^T Pp^-1; T holds F P, so P F^T = T^T
        for ax in range(2):
            for i in range(n):
                dx[ax, i] = X[k + 1, ax, i] - xp[ax, i]
        for ax in range(2):
            for i in range(n):
                s = 0.0
                for j in range(n):
                    s += C[i, j] * dx[ax, j]
                X[k, ax, i] += s
        for i in range(n):                   # P <- P + C (Ps(k+1) - Pp) C^T
            for j in range(n):
                D[i, j] = P[k + 1, i, j] - Pp[i, j]
        congruence(n, C, D, T, P[k], 1.0, P[k])
