"""The columnar tracking engine: the gated filter of every track of a table of position fixes in one
compiled pass, from each track's first fix or continued from its saved state.

Layout (shared/DESIGN.md, "Many tracks"): the fixes of B tracks are flat
columns sorted by (track, time); track b is rows ``offsets[b]:offsets[b+1]``.
The kernel loops over tracks with ``prange`` and over a track's fixes in
order; no Python runs per track, and each block of tracks allocates one
workspace (:func:`._chain.work`), nothing per track or per fix.

One track's complete filter state -- the estimate, the pending manoeuvre
candidate, the run of rejected fixes, the counters -- is one row of float64
(:data:`STATE_FIELDS`, :func:`state_size`), so that :func:`advance_tracks`
continues many tracks from their saved states with their new fixes in one
call, and :func:`filter_tracks` is the same kernel from empty states
(optionally followed by the RTS pass).  A live server keeps one row per device
and stores it as bytes (:func:`state_to_bytes`).  The filter itself (the
two-level NIS gate with a one-fix lookahead, restarts) is the one of
:mod:`._gated`, specialised to the integrator chains of :mod:`._chain`, and
equal to that per-track reference to rounding (tests).

Rows decided again later.  Two rules revise the decision on an earlier fix:
the fix after a manoeuvre candidate decides whether it was a manoeuvre or an
outlier (one fix back), and a restart relabels the rejected fixes of its run,
and those just before it that lie inside the gate of the new stretch's state
predicted back to them, as the start of the new stretch (flag reset, the new
stretch's state; at most :data:`STREAK_CAP` fixes back, the rejected fixes the
state keeps).  Rows of the same call are rewritten in place; rows
of an earlier call are reported in a :class:`Revisions` record (what each of
them is now), so that a track advanced piece by piece ends with the same
rows, NIS and counters as one run over all its fixes, bit for bit.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numba as nb
import numpy as np

from .._core.threads import launch
from ..errors import DTypeError, ParameterError, ShapeError
from ._chain import (BLOCKS, INLINE, LOG2PI, M_C, M_D, M_F, M_P, M_PC, M_PI, M_PP, M_QU, M_RF, M_RP, M_RPP, M_RQU,
                     M_RT, M_RUN, M_T, M_UA, M_UT, MAX_ORDER, PAR, S_DX, S_RUN, S_RX, S_RXP, S_X, S_XC, S_XP, SEQ, V_UK,
                     congruence, copy_state, info_start, innovation, inverse, predict, product, transition, update,
                     work)

__all__ = ["FLAGS", "INIT", "UPDATE", "OUTLIER", "PREDICTED", "RESET", "MANOEUVRE", "MANOEUVRE_FACTOR",
           "MAX_ORDER", "STREAK_CAP", "STATE_VERSION", "STATE_FIELDS", "state_size", "empty_states",
           "Revisions", "advance_tracks", "filter_tracks", "state_to_bytes", "state_from_bytes"]

#: Per-point flags of a tracking result (the output's ``flag`` column), by index.
FLAGS = ("update", "outlier", "predicted", "reset", "init", "manoeuvre")
UPDATE, OUTLIER, PREDICTED, RESET, INIT, MANOEUVRE = range(6)
#: Process noise of the manoeuvre hypothesis, as a multiple of the model's density q.
MANOEUVRE_FACTOR = 10.0
#: The rejected fixes in a row that a track's state keeps (the restart test's run and the fixes
#: before it that a restart may relabel).
STREAK_CAP = 16

# ---- one track's state: a row of float64 --------------------------------------------------------------
#: Version of the state layout (bump it when the layout changes; :func:`state_from_bytes` checks it).
STATE_VERSION = 2
#: The scalar fields at the start of a state row, in order.  Then, for a chain of order r and
#: n = r + 1 states per axis (the chain and the fix error's slow part): the estimate x (2, n) and its
#: covariance P (n, n) after the last fix; the coasting state (the prediction) at a pending manoeuvre
#: candidate, x (2, n) and P (n, n); the candidate's fix (east, north, unit variance w); and the last
#: STREAK_CAP rejected fixes of the current run, oldest first, as four blocks of STREAK_CAP: times, east,
#: north, w.
STATE_FIELDS = (
    "fixes",        # fixes taken so far (0: an empty state; the next fix initialises the track)
    "t_last",       # time of the last fix (s)
    "pending",      # 1 if the last fix is a manoeuvre candidate (the next fix decides)
    "cand_nis",     # the candidate's NIS against the nominal prediction (its NIS if it is an outlier)
    "cand_loglik",  # its log-likelihood as a manoeuvre
    "cand_nis_m",   # its NIS under the manoeuvre hypothesis (its NIS if it is a manoeuvre)
    "window",       # rejected fixes in the restart test's window (<= max_rej)
    "streak",       # rejected fixes in a row (the state keeps the last STREAK_CAP)
    "before_flag",  # the flag of the fix before that run (a restart's reset rows join a reset before them)
    "loglik", "updates", "outliers", "resets", "nis_sum", "manoeuvres",   # the track's counters so far
)
(_FIXES, _T_LAST, _PENDING, _CAND_E, _CAND_LL, _CAND_EM, _WINDOW, _STREAK, _BEFORE, _LOGLIK, _UPDATES, _OUTLIERS,
 _RESETS, _NIS_SUM, _MANOEUVRES) = range(len(STATE_FIELDS))
_HEADER = len(STATE_FIELDS)


@nb.njit(**INLINE)
def _layout(n):
    """Offsets of x, P, the coasting x and P, the candidate's fix, the streak, and the row's size, for n
    states per axis."""
    x0 = _HEADER
    p0 = x0 + 2 * n
    xc0 = p0 + n * n
    pc0 = xc0 + 2 * n
    cand0 = pc0 + n * n
    streak0 = cand0 + 3
    return x0, p0, xc0, pc0, cand0, streak0, streak0 + 4 * STREAK_CAP


def state_size(order: int) -> int:
    """The length of one track's state row for a chain of ``order`` states per axis (2 cv, 3 ca)."""
    return _layout.py_func(order + 1)[-1]


def empty_states(B: int, order: int) -> np.ndarray:
    """(B, state_size(order)) empty states: each track's next fix initialises it (flag init)."""
    return np.zeros((B, state_size(order)))


@dataclass(frozen=True, eq=False)
class Revisions:
    """What :func:`advance_tracks` decided again about fixes of earlier calls (see the module doc).

    n     (B,) how many fixes before the call's first fix of track b were revised: entry i < n[b]
          is the fix i + 1 rows before it (the most recent first)
    flag  (B, R) their flags now; nis (B, R) their NIS now (NaN: unchanged)
    X, P  (B, R, 2, order + 1), (B, R, order + 1, order + 1) their states now (written where the call
          stores states)
    R = STREAK_CAP holds every revision a call can make.
    """

    n: np.ndarray
    flag: np.ndarray
    nis: np.ndarray
    X: np.ndarray
    P: np.ndarray

    @classmethod
    def empty(cls, B: int, order: int) -> Revisions:
        R, n = STREAK_CAP, order + 1
        return cls(np.zeros(B, np.int64), np.zeros((B, R), np.int8), np.full((B, R), np.nan),
                   np.zeros((B, R, 2, n)), np.zeros((B, R, n, n)))


# ---- the per-track filter ------------------------------------------------------------------------------

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
    streak = int(st[_STREAK])
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
    st[_STREAK] = streak
    st[_OUTLIERS] += 1.0
    window = min(int(st[_WINDOW]) + 1, max_rej)
    st[_WINDOW] = window
    if window == max_rej and _restart(bt, bze, bzn, bw, L, c, MANOEUVRE_FACTOR * q, sb2, tau, order, max_rej, gate,
                                      x, P, wk):
        relabelled, whole = _after_reset(k, L, streak, max_rej, bt, bze, bzn, bw, c, q, sb2, tau, gate, order, store,
                                         X, Pout, flag, nis, rev_n, rev_flag, rev_nis, rev_X, rev_P, wk)
        st[_OUTLIERS] -= 1.0 + relabelled
        if not (whole and st[_BEFORE] == RESET):   # a restart run is one reset (it may join one before it)
            st[_RESETS] += 1.0
        _end_streak(st, RESET)
        return RESET
    copy_state(order + 1, x_coast, P_coast, x, P)
    return OUTLIER


@nb.njit(**INLINE)
def _end_streak(st, f):
    """A fix flagged f that is not rejected ends the run of rejections."""
    st[_WINDOW] = 0.0
    st[_STREAK] = 0.0
    st[_BEFORE] = f


@nb.njit(**INLINE)
def _confirm(st):
    """The pending candidate is a manoeuvre: its log-likelihood, NIS and count join the counters."""
    st[_LOGLIK] += st[_CAND_LL]
    st[_NIS_SUM] += st[_CAND_EM]
    st[_MANOEUVRES] += 1.0
    _end_streak(st, MANOEUVRE)


@nb.njit(**INLINE)
def _load(n, st, x0, p0, x, P):
    for a in range(2):
        for i in range(n):
            x[a, i] = st[x0 + a * n + i]
    for i in range(n):
        for j in range(n):
            P[i, j] = st[p0 + i * n + j]


@nb.njit(**INLINE)
def _save(n, st, x0, p0, x, P):
    for a in range(2):
        for i in range(n):
            st[x0 + a * n + i] = x[a, i]
    for i in range(n):
        for j in range(n):
            st[p0 + i * n + j] = P[i, j]


@nb.njit(**SEQ)
def _advance_track(st, t, ze, zn, w, c, q, sb2, tau, order, prior, gate, max_rej, max_gap, store, X, P, nis, flag,
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
    if n_rows == 0 and st[_FIXES] == 0.0:
        return   # an empty track without fixes: nothing to report
    n = order + 1
    hb = order
    mats, sts, vec, _, _ = wk
    F, Qu, T, Pc, Pp, P_coast = mats[M_F], mats[M_QU], mats[M_T], mats[M_P], mats[M_PP], mats[M_PC]
    UA, UT, uk = mats[M_UA], mats[M_UT], vec[V_UK]
    x, xp, x_coast = sts[S_X], sts[S_XP], sts[S_XC]
    x0, p0, xc0, pc0, cand0, streak0, _ = _layout(n)
    qm = MANOEUVRE_FACTOR * q
    rev_n[0] = 0
    for d in range(rev_nis.shape[0]):
        rev_nis[d] = np.nan
    if st[_FIXES] > 0.0:
        _load(n, st, x0, p0, x, Pc)
        _load(n, st, xc0, pc0, x_coast, P_coast)
    pending = st[_PENDING] != 0.0
    t_last = st[_T_LAST]
    for k in range(n_rows):
        rk = c * w[k]
        if st[_FIXES] == 0.0 or t[k] - t_last > max_gap:   # a track's or a segment's first fix
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
            st[_FIXES] += 1.0
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
                _put_state(n, k - 1, f, st[_CAND_E], x, Pc, store, X, P, flag, nis,
                           rev_n, rev_flag, rev_nis, rev_X, rev_P)
                predict(n, F, Qu, q, qb, x, Pc, xp, Pp, T)
                e, S = innovation(n, hb, xp, Pp, rk, ze[k], zn[k])
        nis[k] = e
        if e <= gate:
            e, S = update(n, hb, xp, Pp, rk, ze[k], zn[k], x, Pc, UA, UT, uk)
            flag[k] = UPDATE
            st[_LOGLIK] -= 0.5 * (e + 2.0 * math.log(S) + 2.0 * LOG2PI)
            st[_NIS_SUM] += nis[k]
            st[_UPDATES] += 1.0
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
                st[_CAND_E] = e
                st[_CAND_LL] = -0.5 * (em + 2.0 * math.log(Sm) + 2.0 * LOG2PI)
                st[_CAND_EM] = em
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
        st[_FIXES] += 1.0
    st[_T_LAST] = t_last
    st[_PENDING] = 1.0 if pending else 0.0
    _save(n, st, x0, p0, x, Pc)
    _save(n, st, xc0, pc0, x_coast, P_coast)
    stats[0] = st[_LOGLIK]
    stats[1] = st[_UPDATES]
    stats[2] = st[_OUTLIERS]
    stats[3] = st[_RESETS]
    stats[4] = st[_NIS_SUM]
    stats[5] = st[_MANOEUVRES]
    if pending:                           # a candidate at the last fix so far counts as a manoeuvre
        stats[0] += st[_CAND_LL]
        stats[4] += st[_CAND_EM]
        stats[5] += 1.0


@nb.njit(**SEQ)
def _smooth_track(t, ze, zn, w, c, q, sb2, tau, order, gate, flag, X, P, wk):
    """RTS backward pass over one track's X, P (filtered -> smoothed, in place), separately on
    each stretch that starts at a track's or segment's first fix (INIT) or at a reset.  The step to
    a manoeuvre takes the manoeuvre's process noise, as the filter did (its level found again: the
    first of MANOEUVRE_FACTOR q, MANOEUVRE_FACTOR^2 q whose gate the fix passes from X[k], P[k]).

    The backward recursion of :mod:`mptrack._core.rts` written out for the engine's shared covariance of
    two axes (one smoother gain C for both): a documented exception to the one RTS pass, tested
    against it through :func:`._gated.smooth_gated` (tests/tracking/test_tracking_engine.py)."""
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


# ---- the parallel kernel, compiled once per model order ------------------------------------------------

def _make_kernel(order: int):
    """The parallel kernel with ``order`` a compile-time constant (the small per-fix loops unroll;
    a runtime order made them 3x slower).  numba caches each closure per constant."""

    @nb.njit(**PAR)
    def advance_kernel(states, offsets, t, ze, zn, w, c, q, sb2, tau, prior, gate, max_rej, max_gap, store, smooth,
                       X, P, nis, flag, stats, rev_n, rev_flag, rev_nis, rev_X, rev_P):
        B = offsets.shape[0] - 1
        nblk = min(B, BLOCKS)
        for blk in nb.prange(nblk):
            wk = work(order + 1, STREAK_CAP, STREAK_CAP)
            for b in range(blk * B // nblk, (blk + 1) * B // nblk):
                a0 = offsets[b]
                b0 = offsets[b + 1]
                _advance_track(states[b], t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], c[b], q[b], sb2[b], tau[b], order,
                               prior, gate, max_rej, max_gap, store, X[a0:b0], P[a0:b0], nis[a0:b0], flag[a0:b0],
                               stats[b], rev_n[b:b + 1], rev_flag[b], rev_nis[b], rev_X[b], rev_P[b], wk)
                if smooth and store and b0 > a0:
                    _smooth_track(t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], c[b], q[b], sb2[b], tau[b], order, gate,
                                  flag[a0:b0], X[a0:b0], P[a0:b0], wk)

    return advance_kernel


_KERNELS = {}


def _kernel(order: int):
    if order not in _KERNELS:
        if order not in (2, 3):
            raise ValueError(f"order: the engine runs integrator chains of order 2 or 3, got {order}")
        _KERNELS[order] = _make_kernel(order)
    return _KERNELS[order]


def _no_revisions(B: int, order: int) -> tuple:
    n = order + 1
    return (np.zeros(B, np.int64), np.zeros((B, 0), np.int8), np.zeros((B, 0)), np.zeros((B, 0, 2, n)),
            np.zeros((B, 0, n, n)))


def filter_tracks(offsets, t, ze, zn, w, c, q, sb2, tau, order, prior, gate, max_rej, max_gap, store, smooth, X, P,
                  nis, flag, stats):
    """Gated Kalman filter (and RTS smoother) of every track from its first fix; fills the outputs in place.

    offsets  (B+1,) track b is rows offsets[b]:offsets[b+1]; rows in time order
    t, ze, zn  (N,) seconds, east and north metres of the fixes
    w, c     the white part of the fix error of row k in track b has variance c[b] w[k] (m^2 per axis)
    q        (B,) process-noise density of each track (m^2/s^3 for order 2)
    sb2, tau (B,) the fix error's slow part: stationary variance (m^2 per axis; 0: none) and time constant (s)
    order    chain states per axis: 2 (cv) or 3 (ca); the state has n = order + 1 per axis
    prior    (order,) prior variances of the derivatives at a track's first fix (entry 0 unused)
    gate     NIS threshold (inf: no gating): a fix above it is tried against the manoeuvre
             hypothesis (density MANOEUVRE_FACTOR q) and else rejected; ``max_rej`` rejections in a
             row restart the track if they agree with each other (:func:`_restart`)
    max_gap  a fix more than this many seconds after the last starts a new segment (inf: never)
    X, P     (N, 2, n), (N, n, n): the states, written if ``store`` (else left as they are)
    smooth   replace the stored filtered states by RTS-smoothed ones
    nis, flag (N,)  NIS of each fix (NaN at a track's first fix), index into FLAGS
    stats    (B, 6)  loglik, updates, outliers, resets, NIS sum of the updates and manoeuvres, manoeuvres

    The same kernel as :func:`advance_tracks`, from empty states, in one call.
    """
    B = len(offsets) - 1
    _kernel(order)(empty_states(B, order), offsets, t, ze, zn, w, c, q, sb2, tau, prior, gate, max_rej, max_gap, store,
                   smooth, X, P, nis, flag, stats, *_no_revisions(B, order))


def advance_tracks(states, offsets, t, ze, zn, w, c, q, sb2, tau, order, prior, gate, max_rej, max_gap, X, P, nis,
                   flag, stats, revisions: Revisions | None = None, *, store: bool = True) -> None:
    """Continue the gated filter of B tracks from their states with their new fixes, in one call.

    Parameters
    ----------
    states : (B, state_size(order)) float64
        Each track's state (:func:`empty_states` for a new track); updated in place.
    offsets : (B+1,) int64
        Track b's new fixes are rows offsets[b]:offsets[b+1] of the columns, in time order, none
        before the track's last fix (a track without new fixes is left as it is).
    t, ze, zn, w : (N,) float64
        Times (s), east and north (m) of the fixes, and their unit variances: the white part of fix
        k's error in track b has variance c[b] w[k] per axis.
    c, q, sb2, tau : (B,) float64
        Fix-variance factor, process-noise density, the fix error's slow part (stationary variance,
        m^2 per axis, and time constant, s) of each track for these fixes.
    order, prior, gate, max_rej, max_gap
        As in :func:`filter_tracks`.
    X, P, nis, flag : (N, 2, order + 1), (N, order + 1, order + 1), (N,), (N,) int8
        Written for the new rows: each fix's state (if ``store``), NIS and flag, as decided by the
        end of this call.
    stats : (B, 6) float64
        Written: each track's counters over all its fixes so far (:func:`filter_tracks`).
    revisions : Revisions or None
        Filled with the fixes of earlier calls whose decision this call revised (the module doc);
        None: not reported.

    Raises
    ------
    ShapeError, DTypeError, ParameterError
        An array of the wrong shape or dtype, offsets that do not delimit the rows, a fix before
        its track's last fix or out of time order, a non-finite fix, noise parameters out of range.

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    .. [2] A. Gelb (ed.), Applied Optimal Estimation, MIT Press, 1974.
    """
    order = _check_order(order)
    n = order + 1
    states = _array("states", states, np.float64, 2)
    B = states.shape[0]
    if states.shape[1] != state_size(order):
        raise ShapeError(f"states: expected shape ({B}, {state_size(order)}) for order {order}, got {states.shape}")
    offsets = _array("offsets", offsets, np.int64, 1)
    t, ze, zn, w = (_array(k, v, np.float64, 1) for k, v in (("t", t), ("ze", ze), ("zn", zn), ("w", w)))
    N = t.shape[0]
    if offsets.shape != (B + 1,) or offsets[0] != 0 or offsets[-1] != N or np.any(np.diff(offsets) < 0):
        raise ParameterError(f"offsets: expected {B + 1} non-decreasing row offsets from 0 to {N}")
    for name, a in (("ze", ze), ("zn", zn), ("w", w)):
        if a.shape != (N,):
            raise ShapeError(f"{name}: expected shape ({N},), got {a.shape}")
    if not (np.isfinite(t).all() and np.isfinite(ze).all() and np.isfinite(zn).all() and (w > 0).all()
            and np.isfinite(w).all()):
        raise ParameterError("t, ze, zn, w: expected finite fixes with positive unit variances")
    counts = np.diff(offsets)
    starts = offsets[:-1][counts > 0]
    last = states[counts > 0, _T_LAST]
    fresh = states[counts > 0, _FIXES] == 0
    if np.any(np.diff(t) < 0) and np.any((np.diff(t) < 0) & ~np.isin(np.arange(1, N), starts)):
        raise ParameterError("t: expected each track's new fixes in time order")
    if np.any(~fresh & (t[starts] < last)):
        b = int(np.flatnonzero(counts > 0)[np.flatnonzero(~fresh & (t[starts] < last))[0]])
        raise ParameterError(f"t: track {b}'s first new fix (t = {t[offsets[b]]!r}) is before its last fix "
                             f"(t = {states[b, _T_LAST]!r}); a late fix cannot enter the filter's past")
    c, q, sb2, tau = (_array(k, v, np.float64, 1) for k, v in (("c", c), ("q", q), ("sb2", sb2), ("tau", tau)))
    for name, a in (("c", c), ("q", q), ("sb2", sb2), ("tau", tau)):
        if a.shape != (B,):
            raise ShapeError(f"{name}: expected shape ({B},), got {a.shape}")
    if not ((c > 0).all() and (q >= 0).all() and (sb2 >= 0).all() and (tau > 0).all()
            and np.isfinite(c).all() and np.isfinite(q).all() and np.isfinite(sb2).all()):
        raise ParameterError("c, q, sb2, tau: expected finite c > 0, q >= 0, sb2 >= 0 and tau > 0 (tau may be inf)")
    prior = _array("prior", prior, np.float64, 1)
    if prior.shape != (order,):
        raise ShapeError(f"prior: expected shape ({order},), got {prior.shape}")
    if not order + 1 <= int(max_rej) <= STREAK_CAP:
        raise ParameterError(f"max_rej: expected {order + 1} to {STREAK_CAP} rejections, got {max_rej!r}")
    if not float(max_gap) > 0:
        raise ParameterError(f"max_gap: expected a positive number of seconds (inf: never), got {max_gap!r}")
    for name, a, shape in (("X", X, (N, 2, n)), ("P", P, (N, n, n)), ("nis", nis, (N,)),
                           ("flag", flag, (N,)), ("stats", stats, (B, 6))):
        if a.shape != shape:
            raise ShapeError(f"{name}: expected shape {shape}, got {a.shape}")
    if flag.dtype != np.int8:
        raise DTypeError(f"flag: expected int8, got {flag.dtype}")
    rev = _no_revisions(B, order) if revisions is None else (revisions.n, revisions.flag, revisions.nis,
                                                             revisions.X, revisions.P)
    # a live server's batches are small: on the calling thread, not waking the others (_core.threads)
    launch(_kernel(order), N, states, offsets, t, ze, zn, w, c, q, sb2, tau, prior, float(gate), int(max_rej),
           float(max_gap), bool(store), False, X, P, nis, flag, stats, *rev)


def _check_order(order) -> int:
    if order not in (2, 3):
        raise ParameterError(f"order: the engine runs integrator chains of order 2 or 3, got {order!r}")
    return int(order)


def _array(name: str, a, dtype, ndim: int) -> np.ndarray:
    if not isinstance(a, np.ndarray) or a.dtype != dtype or a.ndim != ndim or not a.flags.c_contiguous:
        raise DTypeError(f"{name}: expected a C-contiguous {ndim}-D {np.dtype(dtype).name} array, got "
                         f"{type(a).__name__}" + (f" {a.dtype} of shape {a.shape}" if isinstance(a, np.ndarray) else ""))
    return a


# ---- one track's state as bytes ------------------------------------------------------------------------

_MAGIC = b"MPTS"
_HEAD = struct.Struct("<4sHBBI")   # magic, layout version, order, streak cap, number of float64


def state_to_bytes(state, order: int) -> bytes:
    """One track's state row as bytes (a header with the layout version, then little-endian float64)."""
    order = _check_order(order)
    row = np.asarray(state, dtype=np.float64)
    if row.shape != (state_size(order),):
        raise ShapeError(f"state: expected one state row of {state_size(order)} values for order {order}, "
                         f"got shape {row.shape}")
    return _HEAD.pack(_MAGIC, STATE_VERSION, order, STREAK_CAP, row.size) + row.astype("<f8").tobytes()


def state_from_bytes(data: bytes) -> tuple[np.ndarray, int]:
    """(state row, order) from :func:`state_to_bytes`; a ParameterError names what does not match."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise DTypeError(f"data: expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) < _HEAD.size:
        raise ParameterError(f"data: {len(data)} bytes is too short for a track state")
    magic, version, order, cap, n = _HEAD.unpack_from(data)
    if magic != _MAGIC:
        raise ParameterError("data: not a track state (its first bytes are not the state's magic)")
    if version != STATE_VERSION or cap != STREAK_CAP:
        raise ParameterError(f"data: a track state of layout version {version} (streak {cap}); this mptrack reads "
                             f"version {STATE_VERSION} (streak {STREAK_CAP}): restart the track from its fixes")
    if order not in (2, 3) or n != state_size(order) or len(data) != _HEAD.size + 8 * n:
        raise ParameterError(f"data: a track state of order {order} with {n} values in {len(data)} bytes does not "
                             "match its layout")
    return np.frombuffer(data, dtype="<f8", offset=_HEAD.size).astype(np.float64), int(order)
