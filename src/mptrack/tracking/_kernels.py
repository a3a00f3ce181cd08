"""The gated irregular-time Kalman loop of :func:`kalman_filter_gated`, compiled (numba).

Same equations as :func:`mptrack.linear.kalman_step` per step (tests check the
result against :func:`mptrack.linear.kalman_filter_irregular`), plus the NIS
gate and the straight-line reset of the module doc of ``_gated``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_LOG2PI = np.log(2.0 * np.pi)


@njit(cache=True)
def _line_consistent(t, z, R, rej, gate, coef):
    """Fit z = a + b (t - t_last) per component through rows ``rej``; coef <- (a, b); True if every
    residual's NIS is within ``gate``."""
    N = rej.shape[0]
    m = z.shape[1]
    t_last = t[rej[N - 1]]
    s1 = 0.0
    s2 = 0.0
    for j in range(N):
        d = t[rej[j]] - t_last
        s1 += d
        s2 += d * d
        for i in range(m):
            if np.isnan(z[rej[j], i]):
                return False
    det = N * s2 - s1 * s1
    if det <= 0.0:
        return False
    for i in range(m):
        sz = 0.0
        stz = 0.0
        for j in range(N):
            d = t[rej[j]] - t_last
            sz += z[rej[j], i]
            stz += d * z[rej[j], i]
        coef[0, i] = (s2 * sz - s1 * stz) / det
        coef[1, i] = (N * stz - s1 * sz) / det
    for j in range(N):
        d = t[rej[j]] - t_last
        r = np.empty(m)
        for i in range(m):
            r[i] = z[rej[j], i] - coef[0, i] - coef[1, i] * d
        if r @ np.linalg.solve(R[rej[j]], r) > gate:
            return False
    return True


@njit(cache=True)
def gated_loop(t, F, Q, H, R, z, x, P, gates, use_gate, max_rej, reset_P, picks, vels,
               xs, Ps, xp, Pp, nis, flag):
    """Run the gated filter; fills xs, Ps, xp, Pp, nis, flag in place; returns the log-likelihood.

    gates[d] is the NIS threshold for d measured components; picks[i] the state entry measured
    by row i of H, vels[i] its velocity entry (-1 if none).
    """
    T, m = z.shape
    rej = np.empty(max_rej, dtype=np.int64)
    nrej = 0
    coef = np.empty((2, m))
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
        PHt = P_pred @ Hk.T
        S = Hk @ PHt + Rk
        S_inv = np.linalg.inv(S)
        e = nu @ S_inv @ nu
        nis[k] = e
        if use_gate and e > gates[mk]:
            if nrej == max_rej:
                rej[:-1] = rej[1:]
                nrej -= 1
            rej[nrej] = k
            nrej += 1
            if nrej == max_rej and _line_consistent(t, z, R, rej, gates[m], coef):
                flag[k] = 3
                nrej = 0
                x = x_pred.copy()
                for i in range(m):
                    x[picks[i]] = coef[0, i]
                    if vels[i] >= 0:
                        x[vels[i]] = coef[1, i]
                P = reset_P.copy()
                xs[k] = x
                Ps[k] = P
                continue
            flag[k] = 1
            x, P = x_pred, P_pred
            xs[k] = x
            Ps[k] = P
            continue
        nrej = 0
        K = PHt @ S_inv
        x = x_pred + K @ nu
        P = P_pred - K @ PHt.T
        P = 0.5 * (P + P.T)
        xs[k] = x
        Ps[k] = P
        loglik -= 0.5 * (e + np.log(np.linalg.det(S)) + mk * _LOG2PI)
    return loglik
