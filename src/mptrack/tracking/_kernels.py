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
def _line_consistent(t, z, R, rej, gate, coef, cov):
    """Fit z = a + b (t - t_last) per component through rows ``rej`` (unweighted least squares);
    coef <- (a, b), cov[i] <- (var a, cov ab, var b) of component i given the fixes' variances
    R[j, i, i]; True if every residual's NIS is within ``gate``."""
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
    # cov = G M G, G = (A^T A)^-1 = [[s2, -s1], [-s1, N]] / det, M = sum_j R_jii [[1, d], [d, d^2]]
    G = np.array([[s2, -s1], [-s1, float(N)]]) / det
    for i in range(m):
        M = np.zeros((2, 2))
        for j in range(N):
            d = t[rej[j]] - t_last
            M += R[rej[j], i, i] * np.array([[1.0, d], [d, d * d]])
        C = G @ M @ G
        cov[i, 0] = C[0, 0]
        cov[i, 1] = C[0, 1]
        cov[i, 2] = C[1, 1]
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
    cov = np.empty((m, 3))
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
            if nrej == max_rej and _line_consistent(t, z, R, rej, gates[m], coef, cov):
                flag[k] = 3
                nrej = 0
                # restart from the line: its position, velocity and their covariance; every
                # other state from 0 with its reset_P variance
                x = np.zeros_like(x_pred)
                P = reset_P.copy()
                for i in range(m):
                    for s_ in (picks[i], vels[i]):
                        if s_ >= 0:
                            P[s_, :] = 0.0
                            P[:, s_] = 0.0
                for i in range(m):
                    p_, v_ = picks[i], vels[i]
                    x[p_] = coef[0, i]
                    P[p_, p_] = cov[i, 0]
                    if v_ >= 0:
                        x[v_] = coef[1, i]
                        P[p_, v_] = cov[i, 1]
                        P[v_, p_] = cov[i, 1]
                        P[v_, v_] = cov[i, 2]
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
