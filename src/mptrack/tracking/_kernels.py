"""The gated irregular-time Kalman loop of :func:`kalman_filter_gated`, compiled (numba).

Same equations as :func:`mptrack.linear.kalman_step` per step (tests check the
result against :func:`mptrack.linear.kalman_filter_irregular`), plus the
two-level NIS gate and the restart of the module doc of ``_gated``, on the
general (n, m) matrices of a continuous model.  This is the readable reference
of the tracking engine (:mod:`._engine`), which specialises the same rules to
integrator chains.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import _jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

_LOG2PI = np.log(2.0 * np.pi)


@njit(cache=True)
def _restart(t, z, R, Fs, Qs, H, rej, nrej, factor, start, gate, x_out, P_out):
    """The rejected fixes ``rej`` (consecutive rows) agree with each other under the manoeuvre
    process noise factor * Q: a diffuse start (information form, from zero information) on the
    first ``start`` of them, then every further one passes the NIS gate against the prediction
    from those before it.  If so, x_out, P_out <- the state at the last one and True."""
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
    Y = np.zeros((n, n))
    y = np.zeros(n)
    for j in range(start):
        k = rej[j]
        if j > 0:
            Fi = np.linalg.inv(Fs[k])
            A = Fi.T @ Y @ Fi
            Mi = np.linalg.inv(eye + factor * Qs[k] @ A)
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
    for j in range(start, nrej):
        k = rej[j]
        x = Fs[k] @ x
        P = Fs[k] @ P @ Fs[k].T + factor * Qs[k]
        nu = z[k] - H @ x
        S = H @ P @ H.T + R[k]
        S_inv = np.linalg.inv(S)
        if nu @ S_inv @ nu > gate:
            return False
        K = P @ H.T @ S_inv
        x = x + K @ nu
        P = P - K @ H @ P
        P = 0.5 * (P + P.T)
    x_out[:] = x
    P_out[:, :] = P
    return True


@njit(cache=True)
def _reject(k, t, z, R, F, Q, H, rej, count, factor, start, gate, x_coast, P_coast, x_new, P_new):
    """Measurement k is rejected: add it to the run ``rej`` (count[0] long); returns (flag, x, P):
    3 and the restart state if the full run agrees (:func:`_restart`), else 1 and the coasting state."""
    max_rej = rej.shape[0]
    if count[0] == max_rej:
        rej[:-1] = rej[1:]
        count[0] -= 1
    rej[count[0]] = k
    count[0] += 1
    if count[0] == max_rej and _restart(t, z, R, F, Q, H, rej, max_rej, factor, start, gate, x_new, P_new):
        count[0] = 0
        return 3, x_new.copy(), P_new.copy()
    return 1, x_coast.copy(), P_coast.copy()


@njit(cache=True)
def _after_reset(last, x, P, F, Q, H, R, z, gates, rej, xs, Ps, flag):
    """A restart at ``last`` (the end of the rejection run ``rej``): the run's earlier fixes, and the
    rejected ones just before it that lie inside the gate of the restart state predicted back to
    them (walking back, up to the first that does not), are flagged 3 (reset) and get that state:
    x_(k-1) = F[k]^-1 x_k, P_(k-1) = F[k]^-1 (P_k + Q[k]) F[k]^-T, step by step back from ``last``."""
    xb, Pb = x.copy(), P.copy()
    k = last
    m = rej.shape[0] - 1
    while True:
        if m > 0:
            m -= 1
            j = rej[m]
            inside_run = True
        else:
            j = k - 1
            if j < 1 or flag[j] != 1:
                break
            inside_run = False
        while k > j:              # predict back from k to k - 1
            Fi = np.linalg.inv(F[k])
            xb = Fi @ xb
            Pb = Fi @ (Pb + Q[k]) @ Fi.T
            k -= 1
        if not inside_run:
            idx, nu, S, e = _innovation(xb, Pb, H, R[j], z[j])
            if e > gates[idx.shape[0]]:
                break
        flag[j] = 3
        xs[j] = xb
        Ps[j] = 0.5 * (Pb + Pb.T)


@njit(cache=True)
def _innovation(x_pred, P_pred, H, R, zk):
    """(observed component indices, innovation, its covariance S, NIS) of measurement zk."""
    idx = np.flatnonzero(~np.isnan(zk))
    mk = idx.shape[0]
    Hk = H[idx]
    Rk = np.empty((mk, mk))
    for a in range(mk):
        for b in range(mk):
            Rk[a, b] = R[idx[a], idx[b]]
    nu = zk[idx] - Hk @ x_pred
    S = Hk @ P_pred @ Hk.T + Rk
    e = nu @ np.linalg.inv(S) @ nu if mk else 0.0
    return idx, nu, S, e


@njit(cache=True)
def _kalman_update(x_pred, P_pred, H, idx, nu, S):
    Hk = H[idx]
    PHt = P_pred @ Hk.T
    K = PHt @ np.linalg.inv(S)
    x = x_pred + K @ nu
    P = P_pred - K @ PHt.T
    return x, 0.5 * (P + P.T)


@njit(cache=True)
def gated_loop(t, F, Q, H, R, z, x, P, gates, use_gate, max_rej, factor, start, xs, Ps, xp, Pp, nis, flag):
    """Run the gated filter; fills xs, Ps, xp, Pp, nis, flag in place; returns the log-likelihood.

    gates[d] is the NIS threshold for d measured components.  A measurement above it that passes
    against the prediction with process noise factor * Q[k] is a manoeuvre candidate: the filter
    goes on from that update and the next measurement decides (inside the gate of that track: flag
    5, manoeuvre; else the candidate was an outlier, flag 1, and the filter coasts through it); a
    candidate at the last step is a manoeuvre.  Other measurements above the gate are rejected
    (flag 1); ``max_rej`` rejections in a row restart the filter from them (flag 3) if they agree
    (:func:`_restart`, diffuse start on ``start`` of them), and the run's fixes before the last
    take the restart state (:func:`_after_reset`).
    """
    T, m = z.shape
    n = x.shape[0]
    rej = np.empty(max_rej, dtype=np.int64)
    count = np.zeros(1, dtype=np.int64)
    x_new = np.empty(n)
    P_new = np.empty((n, n))
    x_coast = np.empty(n)
    P_coast = np.empty((n, n))
    pending = False               # measurement k - 1 is a manoeuvre candidate
    cand_e = cand_ll = 0.0        # its nominal NIS and its log-likelihood as a manoeuvre
    loglik = 0.0
    for k in range(T):
        x_pred = F[k] @ x
        P_pred = F[k] @ P @ F[k].T + Q[k]
        xp[k] = x_pred
        Pp[k] = P_pred
        idx, nu, S, e = _innovation(x_pred, P_pred, H, R[k], z[k])
        mk = idx.shape[0]
        if pending:
            pending = False
            if mk == 0 or e <= gates[mk]:      # confirms the manoeuvre at k - 1
                loglik += cand_ll
                count[0] = 0
            else:                              # the candidate at k - 1 was an outlier
                nis[k - 1] = cand_e
                f1, x, P = _reject(k - 1, t, z, R, F, Q, H, rej, count, factor, start, gates[m],
                                   x_coast, P_coast, x_new, P_new)
                flag[k - 1] = f1
                if f1 == 3:
                    _after_reset(k - 1, x, P, F, Q, H, R, z, gates, rej, xs, Ps, flag)
                xs[k - 1] = x
                Ps[k - 1] = P
                x_pred = F[k] @ x
                P_pred = F[k] @ P @ F[k].T + Q[k]
                xp[k] = x_pred
                Pp[k] = P_pred
                idx, nu, S, e = _innovation(x_pred, P_pred, H, R[k], z[k])
        if mk == 0:
            flag[k] = 2
            x, P = x_pred, P_pred
            xs[k] = x
            Ps[k] = P
            continue
        nis[k] = e
        if not use_gate or e <= gates[mk]:
            count[0] = 0
            x, P = _kalman_update(x_pred, P_pred, H, idx, nu, S)
            flag[k] = 0
            loglik -= 0.5 * (e + np.log(np.linalg.det(S)) + mk * _LOG2PI)
        else:
            x_coast[:] = x_pred
            P_coast[:, :] = P_pred
            P_m = P_pred + (factor - 1.0) * Q[k]
            idx, nu, S_m, em = _innovation(x_pred, P_m, H, R[k], z[k])
            if em <= gates[mk]:
                x, P = _kalman_update(x_pred, P_m, H, idx, nu, S_m)
                flag[k] = 5
                nis[k] = em
                pending = True
                cand_e, cand_ll = e, -0.5 * (em + np.log(np.linalg.det(S_m)) + mk * _LOG2PI)
            else:
                f1, x, P = _reject(k, t, z, R, F, Q, H, rej, count, factor, start, gates[m],
                                   x_coast, P_coast, x_new, P_new)
                flag[k] = f1
                if f1 == 3:
                    _after_reset(k, x, P, F, Q, H, R, z, gates, rej, xs, Ps, flag)
        xs[k] = x
        Ps[k] = P
    if pending:                                # a candidate at the last step is a manoeuvre
        loglik += cand_ll
    return loglik
