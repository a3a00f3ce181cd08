"""The gated irregular-time Kalman loop of :func:`kalman_filter_gated`, compiled (numba).

Same equations as :func:`mptrack.linear.kalman_step` per step, run by the one
compiled predict/update of :mod:`mptrack._core.kalman` (tests check the result
against :func:`mptrack.linear.kalman_filter_irregular`), plus the
two-level NIS gate and the restart of the module doc of ``_gated``, on the
general (n, m) matrices of a continuous model.  This is the readable reference
of the tracking engine (:mod:`._engine`), which specialises the same rules to
integrator chains.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.kalman import LOG2PI, OK, apply_gain, innovation, predict, update, whiten, workspace
from ._state import STREAK_CAP

#: A restart relabels at most this many fixes before it (the engine's state keeps the last STREAK_CAP rejected fixes).
RELABEL_CAP = STREAK_CAP - 1


@njit(cache=True)
def _restart(t, z, R, Fs, Qs, H, Y0, rej, nrej, start, gate, x_out, P_out, xr, Pr, ws):
    """The rejected fixes ``rej`` (consecutive rows) agree with each other under the manoeuvre
    process noise Qs: a diffuse start (information form, from the information Y0 of the states that
    have a prior of their own, zero for the others) on the first ``start`` of them, then every
    further one passes the NIS gate against the prediction from those before it.  If so, x_out,
    P_out <- the state at the last one and True; xr[m], Pr[m] <- the state at the run's fix m, for
    m >= start - 1 (the filter started at the run's first fix)."""
    n = H.shape[1]
    for j in range(nrej):
        if np.isnan(z[rej[j]]).any():
            return False
    distinct = 1
    for j in range(1, start):
        if t[rej[j]] != t[rej[j - 1]]:
            distinct += 1
    if distinct < start:  # the diffuse start needs measurements at ``start`` distinct times
        return False
    eye = np.eye(n)
    Y = Y0.copy()
    y = np.zeros(n)
    for j in range(start):
        k = rej[j]
        if j > 0:
            Fi = np.linalg.inv(Fs[k])
            A = Fi.T @ Y @ Fi
            Mi = np.linalg.inv(eye + Qs[k] @ A)
            Y = A @ Mi
            Y = 0.5 * (Y + Y.T)
            y = Mi.T @ (Fi.T @ y)
        Ri = np.linalg.inv(R[k])
        Y = Y + H.T @ Ri @ H
        y = y + H.T @ Ri @ z[k]
    w = np.linalg.eigvalsh(Y)
    if not w[0] > 1e-13 * w[-1]:
        return False
    P = np.linalg.inv(Y)
    P = 0.5 * (P + P.T)
    x = P @ y
    xr[start - 1] = x
    Pr[start - 1] = P
    periods = np.zeros(H.shape[0])
    for j in range(start, nrej):
        k = rej[j]
        predict(Fs[k], Qs[k], x, P, ws)
        q = innovation(P, H, H @ x, R[k], z, k, periods, ws)
        ok, e, _ = whiten(ws, q)
        if not ok or e > gate:
            return False
        apply_gain(x, P, ws, q, True)
        xr[j] = x
        Pr[j] = P
    x_out[:] = x
    P_out[:, :] = P
    return True


@njit(cache=True)
def _reject(k, t, z, R, F, Qm, H, Y0, rej, count, start, gate, x_coast, P_coast, x_new, P_new, xr, Pr, ws):
    """Measurement k is rejected: add it to the run ``rej`` (count[0] long); returns (flag, x, P):
    3 and the restart state if the full run agrees (:func:`_restart`), else 1 and the coasting state."""
    max_rej = rej.shape[0]
    if count[0] == max_rej:
        rej[:-1] = rej[1:]
        count[0] -= 1
    rej[count[0]] = k
    count[0] += 1
    if count[0] == max_rej and _restart(t, z, R, F, Qm, H, Y0, rej, max_rej, start, gate, x_new, P_new, xr, Pr,
                                        ws):
        count[0] = 0
        return 3, x_new.copy(), P_new.copy()
    return 1, x_coast.copy(), P_coast.copy()


@njit(cache=True)
def _after_reset(F, Q, H, R, z, gates, rej, start, xr, Pr, cap, xs, Ps, flag, ws):
    """A restart at the end of the rejection run ``rej``: the run's earlier fixes, and the rejected ones just
    before it that lie inside the gate of the new stretch's state predicted back to them (walking back, up
    to the first that does not; at most ``cap`` fixes in all), are flagged 3 (reset) and get the new
    stretch's state: at the run's fixes from the ``start``-th on, the restart test's (xr, Pr: the filter
    started at the run's first fix); before it, that state predicted back step by step,
    x_(k-1) = F[k]^-1 x_k, P_(k-1) = F[k]^-1 (P_k + Q[k]) F[k]^-T, and updated with the fix there when it
    is one before the run (the new stretch taken back to it, a backward filter)."""
    nrej = rej.shape[0]
    relabelled = 0
    for m in range(nrej - 2, start - 2, -1):
        j = rej[m]
        flag[j] = 3
        xs[j] = xr[m]
        Ps[j] = Pr[m]
        relabelled += 1
    xb, Pb = xr[start - 1].copy(), Pr[start - 1].copy()
    k = rej[start - 1]
    m = start - 1
    while relabelled < cap:
        if m > 0:
            m -= 1
            j = rej[m]
            inside_run = True
        else:
            j = k - 1
            if j < 1 or flag[j] != 1:
                break
            inside_run = False
        while k > j:              # predict back from k to k - 1: F^-1 (x, P + Q) by the core's predict
            xb, Pb = _predicted(np.linalg.inv(F[k]), np.zeros_like(Q[k]), xb, Pb + Q[k], ws)
            k -= 1
        if not inside_run:          # inside the gate of the back prediction: its fix joins the new stretch
            idx, _nu, _S, e = _innovation(xb, Pb, H, R[j], z, j, ws)
            if e > gates[idx.shape[0]]:
                break
            xb, Pb = _kalman_update(xb, Pb, H, R[j], z, j, ws)
        flag[j] = 3
        xs[j] = xb
        Ps[j] = 0.5 * (Pb + Pb.T)
        relabelled += 1


@njit(cache=True)
def _predicted(F, Q, x, P, ws):
    """(F x, F P F^T + Q) as new arrays, by :func:`mptrack._core.kalman.predict`."""
    xp = x.copy()
    Pp = P.copy()
    predict(F, Q, xp, Pp, ws)
    return xp, Pp


@njit(cache=True)
def _innovation(x_pred, P_pred, H, R, z, k, ws):
    """(observed component indices, innovation, its covariance S, NIS) of row k of z (copies out of the
    workspace ws of :func:`mptrack._core.kalman.innovation`); NIS inf when S is not positive definite."""
    q = innovation(P_pred, H, H @ x_pred, R, z, k, np.zeros(H.shape[0]), ws)
    e = 0.0
    if q > 0:
        ok, e, _ = whiten(ws, q)
        if not ok:
            e = np.inf
    idx, (_Hq, _HP, _C, _K, _KR, _Rq, S, _L, _IKH, _A, nu, _w) = ws
    return idx[:q].copy(), nu[:q].copy(), S[:q, :q].copy(), e


@njit(cache=True)
def _record(k, idx, nu, S, nus, Ss):
    """nus[k], Ss[k] at the components idx <- the innovation nu and its covariance S."""
    for a in range(idx.shape[0]):
        nus[k, idx[a]] = nu[a]
        for b in range(idx.shape[0]):
            Ss[k, idx[a], idx[b]] = S[a, b]


@njit(cache=True)
def _kalman_update(x_pred, P_pred, H, R, z, k, ws):
    """x(k/k), P(k/k) from the prediction and row k of z (:func:`mptrack._core.kalman.update`, Joseph
    form: it stays accurate when a long gap makes P huge next to R); NaN when the innovation covariance
    is not positive definite."""
    x = x_pred.copy()
    P = P_pred.copy()
    status, _ = update(x, P, H, H @ x_pred, R, z, k, np.zeros(H.shape[0]), True, ws)
    if status != OK:
        x[:] = np.nan
        P[:, :] = np.nan
    return x, P


@njit(cache=True)
def gated_loop(t, F, Q, Qm, Qs, H, R, z, x, P, Y0, gates, use_gate, max_rej, start, xs, Ps, xp, Pp, nus, Ss, nis,
               flag, level):
    """Run the gated filter; fills xs, Ps, xp, Pp, nus, Ss, nis, flag, level in place (nus, Ss, nis NaN-filled
    by the caller: the innovation, its covariance and the NIS the gate decided on, where a measurement was
    there; level 0 where the step used Q, 1 Qm, 2 Qs -- a manoeuvre's); returns the log-likelihood.

    gates[d] is the NIS threshold for d measured components.  A measurement above it that passes
    against the prediction with the manoeuvre's process noise Qm[k] (or else the sharp manoeuvre's,
    Qs[k]) is a manoeuvre candidate: the filter goes on from that update and the next measurement
    decides (inside the gate of that track: flag 5, manoeuvre; else the candidate was an outlier,
    flag 1, and the filter coasts through it); a candidate at the last step is a manoeuvre.  Other
    measurements above the gate are rejected (flag 1); ``max_rej`` rejections in a row restart the
    filter from them (flag 3) if they agree under Qm (:func:`_restart`, diffuse start on ``start`` of
    them, the states with a prior of their own starting from its information Y0), and the run's fixes
    before the last take the new stretch's state (:func:`_after_reset`).
    """
    T, m = z.shape
    n = x.shape[0]
    rej = np.empty(max_rej, dtype=np.int64)
    count = np.zeros(1, dtype=np.int64)
    x_new = np.empty(n)
    P_new = np.empty((n, n))
    xr = np.empty((max_rej, n))          # a restart test's state at each fix of its run
    Pr = np.empty((max_rej, n, n))
    x_coast = np.empty(n)
    P_coast = np.empty((n, n))
    ws = workspace(n, m)
    pending = False               # measurement k - 1 is a manoeuvre candidate
    cand_e = cand_ll = 0.0        # its nominal NIS and its log-likelihood as a manoeuvre
    cand_idx = np.empty(0, np.int64)
    cand_S = np.empty((0, 0))     # its components and nominal innovation covariance
    loglik = 0.0
    for k in range(T):
        x_pred, P_pred = _predicted(F[k], Q[k], x, P, ws)
        xp[k] = x_pred
        Pp[k] = P_pred
        idx, nu, S, e = _innovation(x_pred, P_pred, H, R[k], z, k, ws)
        mk = idx.shape[0]
        if pending:
            pending = False
            if mk == 0 or e <= gates[mk]:      # confirms the manoeuvre at k - 1
                loglik += cand_ll
                count[0] = 0
            else:                              # the candidate at k - 1 was an outlier
                nis[k - 1] = cand_e
                _record(k - 1, cand_idx, nus[k - 1][cand_idx], cand_S, nus, Ss)
                f1, x, P = _reject(k - 1, t, z, R, F, Qm, H, Y0, rej, count, start, gates[m],
                                   x_coast, P_coast, x_new, P_new, xr, Pr, ws)
                flag[k - 1] = f1
                level[k - 1] = 0
                if f1 == 3:
                    _after_reset(F, Q, H, R, z, gates, rej, start, xr, Pr, RELABEL_CAP, xs, Ps, flag, ws)
                xs[k - 1] = x
                Ps[k - 1] = P
                x_pred, P_pred = _predicted(F[k], Q[k], x, P, ws)
                xp[k] = x_pred
                Pp[k] = P_pred
                idx, nu, S, e = _innovation(x_pred, P_pred, H, R[k], z, k, ws)
        if mk == 0:
            flag[k] = 2
            x, P = x_pred, P_pred
            xs[k] = x
            Ps[k] = P
            continue
        nis[k] = e
        _record(k, idx, nu, S, nus, Ss)
        if not use_gate or e <= gates[mk]:
            count[0] = 0
            x, P = _kalman_update(x_pred, P_pred, H, R[k], z, k, ws)
            flag[k] = 0
            loglik -= 0.5 * (e + np.log(np.linalg.det(S)) + mk * LOG2PI)
        else:
            x_coast[:] = x_pred
            P_coast[:, :] = P_pred
            P_m = P_pred + (Qm[k] - Q[k])
            idx, nu, S_m, em = _innovation(x_pred, P_m, H, R[k], z, k, ws)
            lev = 1
            if em > gates[mk]:                 # the sharp manoeuvre
                P_m = P_pred + (Qs[k] - Q[k])
                idx, nu, S_m, em = _innovation(x_pred, P_m, H, R[k], z, k, ws)
                lev = 2
            if em <= gates[mk]:
                x, P = _kalman_update(x_pred, P_m, H, R[k], z, k, ws)
                flag[k] = 5
                level[k] = lev
                nis[k] = em
                _record(k, idx, nu, S_m, nus, Ss)
                cand_idx, cand_S = idx, S
                pending = True
                cand_e, cand_ll = e, -0.5 * (em + np.log(np.linalg.det(S_m)) + mk * LOG2PI)
            else:
                f1, x, P = _reject(k, t, z, R, F, Qm, H, Y0, rej, count, start, gates[m],
                                   x_coast, P_coast, x_new, P_new, xr, Pr, ws)
                flag[k] = f1
                if f1 == 3:
                    _after_reset(F, Q, H, R, z, gates, rej, start, xr, Pr, RELABEL_CAP, xs, Ps, flag, ws)
        xs[k] = x
        Ps[k] = P
    if pending:                                # a candidate at the last step is a manoeuvre
        loglik += cand_ll
    return loglik
