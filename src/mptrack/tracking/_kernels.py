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
def gated_loop(t, F, Q, H, R, z, x, P, gates, use_gate, max_rej, factor, start, xs, Ps, xp, Pp, nis, flag):
    """Run the gated filter; fills xs, Ps, xp, Pp, nis, flag in place; returns the log-likelihood.

    gates[d] is the NIS threshold for d measured components; a measurement above it is tried
    against the prediction with process noise factor * Q[k] (flag 5, manoeuvre) and else rejected
    (flag 1); ``max_rej`` rejections in a row restart the filter from them (flag 3) if they agree
    (:func:`_restart`, diffuse start on ``start`` of them).
    """
    T, m = z.shape
    n = x.shape[0]
    rej = np.empty(max_rej, dtype=np.int64)
    nrej = 0
    x_new = np.empty(n)
    P_new = np.empty((n, n))
    loglik = 0.0
    for k in range(T):
        x_pred = F[k] @ x
        P_pred = F[k] @ P @ F[k].T + Q[k]
        xp[k] = x_pred
        Pp[k] = P_pred
        idx = np.flatnonzero(~np.isnan(z[k]))
        mk = idx.shape[0]
        if mk == 0:
            flag[k] = 2
            x, P = x_pred, P_pred
            xs[k] = x
            Ps[k] = P
            continue
        Hk = H[idx]
        Rk = np.empty((mk, mk))
        for a in range(mk):
            for b in range(mk):
                Rk[a, b] = R[k, idx[a], idx[b]]
        nu = z[k][idx] - Hk @ x_pred
        S = Hk @ P_pred @ Hk.T + Rk
        e = nu @ np.linalg.inv(S) @ nu
        f = 0
        if use_gate and e > gates[mk]:
            P_pred = P_pred + (factor - 1.0) * Q[k]
            S = Hk @ P_pred @ Hk.T + Rk
            e = nu @ np.linalg.inv(S) @ nu
            f = 5
        nis[k] = e
        if use_gate and e > gates[mk]:
            if nrej == max_rej:
                rej[:-1] = rej[1:]
                nrej -= 1
            rej[nrej] = k
            nrej += 1
            if nrej == max_rej and mk == m and _restart(t, z, R, F, Q, H, rej, nrej, factor, start, gates[m],
                                                        x_new, P_new):
                flag[k] = 3
                nrej = 0
                x, P = x_new.copy(), P_new.copy()
            else:
                flag[k] = 1
                x, P = x_pred, Pp[k]
            xs[k] = x
            Ps[k] = P
            continue
        nrej = 0
        S_inv = np.linalg.inv(S)
        PHt = P_pred @ Hk.T
        K = PHt @ S_inv
        x = x_pred + K @ nu
        P = P_pred - K @ PHt.T
        P = 0.5 * (P + P.T)
        flag[k] = f
        xs[k] = x
        Ps[k] = P
        loglik -= 0.5 * (e + np.log(np.linalg.det(S)) + mk * _LOG2PI)
    return loglik
