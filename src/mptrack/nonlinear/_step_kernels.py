"""Compiled (numba) arithmetic of one EKF / UKF step, shared by every discrete-time Gaussian filter.

The generic filters (:func:`mptrack.nonlinear.ekf_filter`, :func:`~mptrack.nonlinear.ukf_filter` on a
:class:`mptrack.models.NonlinearModel` with the user's f, h, Q, R) evaluate the model in Python and
hand the numbers to these kernels, one call for the covariance prediction and one for the measurement
update, which write into the caller's output rows (no arrays are returned: boxing them costs more than
the arithmetic): the Python overhead per step is then the user's functions plus two or three kernel
calls.  The whole-run
loops of the named models (:mod:`mptrack.nonlinear._named_kernels`) call the same cores, so both paths
do the same arithmetic:

    EKF   P(k/k-1) = F P F^T + Q;  Joseph update (I - K H) P (I - K H)^T + K R K^T
    UKF   x(k/k-1), P(k/k-1) = Σ Wm Y, Σ Wc (Y - x)(Y - x)^T + Q for Y = f(sigma points);
          update with the sigma points of the prediction (Särkkä 2013, alg. 5.14), angles averaged on the
          circle and innovations wrapped into [-π, π) (any period: the continuous-discrete UKF too)

NaN components of z are skipped.  A core reports a problem by a status code instead of raising:
NOT_PD (an innovation covariance without a Cholesky factor), DIVERGED (a non-finite input or result).
The small helpers are inlined in numba's IR (``inline="always"``): as calls they cost the named EKF's
loop about a third of its time (measured against the loop that had them written out).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import _jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

__all__ = ["ekf_predict_into", "ekf_update_into", "sigma_into", "unscented_moments_into", "ukf_update_into",
           "OK", "NOT_PD", "DIVERGED"]

_LOG2PI = float(np.log(2.0 * np.pi))
_TWO_PI = 2.0 * np.pi

OK, NOT_PD, DIVERGED = 0, 1, 2


@njit(cache=True, nogil=True, inline="always")
def _wrap(v, period):
    """v wrapped into [-period/2, period/2) (``wrap_angles``); period 0: v itself."""
    return (v + 0.5 * period) % period - 0.5 * period if period > 0.0 else v


@njit(cache=True, nogil=True, inline="always")
def _cholesky(S, L, q):
    """Lower Cholesky factor of S[:q, :q] into L[:q, :q]; False when S is not positive definite."""
    for i in range(q):
        for j in range(q):
            L[i, j] = 0.0
    for j in range(q):
        s = S[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, q):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


@njit(cache=True, nogil=True, inline="always")
def _chol_solve(L, b, out, q):
    """out[:q] = S^-1 b[:q] with S = L L^T (L[:q, :q])."""
    for i in range(q):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * out[k]
        out[i] = s / L[i, i]
    for i in range(q - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, q):
            s -= L[k, i] * out[k]
        out[i] = s / L[i, i]


@njit(cache=True, nogil=True, inline="always")
def _gain_loglik(L, nu, PHt, K, w, n, q):
    """K[:n, :q] = PHt S^-1 (rows solved with the Cholesky factor L of S, all [:q]) and log N(nu; 0, S)."""
    for a in range(n):
        _chol_solve(L, PHt[a], K[a], q)
    quad = 0.0
    logdet = 0.0
    for i in range(q):
        s = nu[i]
        for k in range(i):
            s -= L[i, k] * w[k]
        w[i] = s / L[i, i]
        quad += w[i] * w[i]
        logdet += np.log(L[i, i])
    return -0.5 * (quad + 2.0 * logdet + q * _LOG2PI)


@njit(cache=True, nogil=True, inline="always")
def _finite(x, P):
    acc = 0.0
    for a in range(x.shape[0]):
        acc += x[a]
        for b in range(x.shape[0]):
            acc += P[a, b]
    return np.isfinite(acc)


@njit(cache=True, nogil=True)
def _symmetrise(P):
    n = P.shape[0]
    for a in range(n):
        for b in range(a + 1, n):
            v = 0.5 * (P[a, b] + P[b, a])
            P[a, b] = v
            P[b, a] = v


@njit(cache=True, nogil=True, inline="always")
def _mul(A, B, out, ni, nk, nj):
    """out[:ni, :nj] = A[:ni, :nk] B[:nk, :nj] (explicit loops: no temporaries, views or BLAS calls for
    these small matrices)."""
    for i in range(ni):
        for j in range(nj):
            acc = 0.0
            for k in range(nk):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@njit(cache=True, nogil=True, inline="always")
def _sym_bt(A, B, out, n, nk):
    """out[:n, :n] = A[:n, :nk] B[:n, :nk]^T for a product known to be symmetric: the upper triangle,
    mirrored (0.5 (P + P^T) up to rounding)."""
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for k in range(nk):
                acc += A[i, k] * B[j, k]
            out[i, j] = acc
            out[j, i] = acc


@njit(cache=True, nogil=True, inline="always")
def _observed(z, k, idx):
    """The indices of the non-NaN components of row k of z into idx; returns their count.  (The cores
    take z and k, not the row z[k]: a view made per step costs a reference count pair, a fifth of the
    named EKF's step.)"""
    q = 0
    for i in range(z.shape[1]):
        if not np.isnan(z[k, i]):
            idx[q] = i
            q += 1
    return q


@njit(cache=True, nogil=True, inline="always")
def _store(x, P, xs, Ps, k):
    """xs[k], Ps[k] = x, P."""
    n = x.shape[0]
    for a in range(n):
        xs[k, a] = x[a]
        for b in range(n):
            Ps[k, a, b] = P[a, b]


# ---------------------------------------------------------------- EKF
@njit(cache=True, nogil=True)
def ekf_workspace(n, m):
    """The work arrays of :func:`_ekf_update`: component indices (m,) and the step's matrices, views of
    one buffer (:func:`_carve`; made once per run by the whole-run loops)."""
    return np.empty(m, np.int64), _carve(np.empty(5 * m * n + 3 * m * m + 2 * m + 2 * n * n), n, m)


@njit(cache=True, nogil=True)
def _carve(buf, n, m):
    """Views of buf: H, HP (m, n), PHt, K, KR (n, m), Rq, S, L (m, m), IKH, A (n, n), nu, w (m,)."""
    a, b, c = m * n, m * m, n * n
    return (buf[0:a].reshape((m, n)), buf[a:2 * a].reshape((m, n)), buf[2 * a:3 * a].reshape((n, m)),
            buf[3 * a:4 * a].reshape((n, m)), buf[4 * a:5 * a].reshape((n, m)),
            buf[5 * a:5 * a + b].reshape((m, m)), buf[5 * a + b:5 * a + 2 * b].reshape((m, m)),
            buf[5 * a + 2 * b:5 * a + 3 * b].reshape((m, m)),
            buf[5 * a + 3 * b:5 * a + 3 * b + c].reshape((n, n)),
            buf[5 * a + 3 * b + c:5 * a + 3 * b + 2 * c].reshape((n, n)),
            buf[5 * a + 3 * b + 2 * c:5 * a + 3 * b + 2 * c + m], buf[5 * a + 3 * b + 2 * c + m:])


@njit(cache=True, nogil=True)
def _cov_predict(F, Q, P, A):
    """P <- F P F^T + Q in place (A: (n, n) work)."""
    n = P.shape[0]
    _mul(F, P, A, n, n, n)
    _sym_bt(A, F, P, n, n)
    for a in range(n):
        for b in range(n):
            P[a, b] += Q[a, b]


@njit(cache=True, nogil=True)
def _ekf_update(x, P, Hf, hx, R, z, k, periods, ws):
    """The Joseph-form EKF update of x, P in place with row k of z (NaN components skipped), the
    Jacobian Hf (m, n), h(x) hx (m,), R (m, m) and periods (m,) (0: not an angle) of all components; ws
    from :func:`ekf_workspace`.
    Returns (status, loglik)."""
    n = x.shape[0]
    idx, (H, HP, PHt, K, KR, Rq, S, L, IKH, A, nu, w) = ws
    q = _observed(z, k, idx)
    if q == 0:
        return OK, 0.0
    for a in range(q):
        i = idx[a]
        for b in range(n):
            H[a, b] = Hf[i, b]
        nu[a] = _wrap(z[k, i] - hx[i], periods[i])
        for b in range(q):
            Rq[a, b] = R[i, idx[b]]
    _mul(H, P, HP, q, n, n)
    _sym_bt(HP, H, S, q, n)
    for a in range(q):
        for b in range(q):
            S[a, b] += Rq[a, b]
    for a in range(n):
        for b in range(q):
            PHt[a, b] = HP[b, a]
    if not _cholesky(S, L, q):
        return NOT_PD, 0.0
    ll = _gain_loglik(L, nu, PHt, K, w, n, q)
    for a in range(n):
        acc = 0.0
        for b in range(q):
            acc += K[a, b] * nu[b]
        x[a] += acc
    _mul(K, H, IKH, n, q, n)
    for a in range(n):
        for b in range(n):
            IKH[a, b] = (1.0 if a == b else 0.0) - IKH[a, b]
    _mul(IKH, P, A, n, n, n)
    _sym_bt(A, IKH, P, n, n)
    _mul(K, Rq, KR, n, q, q)
    for a in range(n):
        for b in range(a, n):
            acc = 0.0
            for c in range(q):
                acc += KR[a, c] * K[b, c]
            P[a, b] += acc
            if b != a:
                P[b, a] = P[a, b]
    return OK, ll


@njit(cache=True, nogil=True)
def ekf_predict_into(F, P, Q, P_out):
    """P_out = F P F^T + Q."""
    n = P.shape[0]
    P_out[:, :] = P
    _cov_predict(F, Q, P_out, np.empty((n, n)))


@njit(cache=True, nogil=True)
def ekf_update_into(x, P, H, hx, R, z, k, periods, x_out, P_out):
    """One EKF update of x, P with row k of z into x_out, P_out: (status, loglik); DIVERGED for
    non-finite input or output."""
    x_out[:] = x
    P_out[:, :] = P
    if not (_finite(x, P) and np.isfinite(H.sum() + hx.sum() + R.sum())):
        return DIVERGED, 0.0
    status, ll = _ekf_update(x_out, P_out, H, hx, R, z, k, periods, ekf_workspace(x.shape[0], z.shape[1]))
    if status == OK and not _finite(x_out, P_out):
        status = DIVERGED
    return status, ll


# ---------------------------------------------------------------- UKF
@njit(cache=True, nogil=True)
def _sigma(x, P, c, X):
    """The 2n+1 sigma points of N(x, P) into X; False when c P has no Cholesky factor."""
    n = x.shape[0]
    L = np.empty((n, n))
    if not _cholesky(c * P, L, n):
        return False
    for a in range(n):
        X[0, a] = x[a]
    for i in range(n):
        for a in range(n):
            X[1 + i, a] = x[a] + L[a, i]
            X[1 + n + i, a] = x[a] - L[a, i]
    return True


@njit(cache=True, nogil=True)
def sigma_into(x, P, c, X):
    """The sigma points x, x ± columns of chol(c P) into X (2n+1, n); False when c P is not positive
    definite (the caller takes the eigenvalue square root)."""
    return _sigma(x, P, c, X)


@njit(cache=True, nogil=True)
def unscented_moments(Y, Wm, Wc, Q):
    """(Σ Wm Y, Σ Wc (Y - m)(Y - m)^T + Q), symmetrised: the unscented prediction from Y = f(X)."""
    N = Y.shape[0]
    x = Wm @ Y
    dY = Y - x
    P = (Wc.reshape(N, 1) * dY).T @ dY + Q
    _symmetrise(P)
    return x, P


@njit(cache=True, nogil=True)
def unscented_moments_into(Y, Wm, Wc, Q, x_out, P_out):
    """:func:`unscented_moments` into x_out, P_out."""
    x, P = unscented_moments(Y, Wm, Wc, Q)
    x_out[:] = x
    P_out[:, :] = P


@njit(cache=True, nogil=True)
def _ukf_update(x, P, X, Zf, Wm, Wc, R, z, k, periods):
    """The unscented update of N(x, P) (sigma points X, their measurements Zf (N, m)) with row k of z
    (NaN components skipped); components of period > 0 are averaged on the circle and wrapped.
    Returns (status, x, P, loglik) with new x, P."""
    N, m = Zf.shape
    n = x.shape[0]
    idx = np.empty(m, np.int64)
    q = _observed(z, k, idx)
    if q == 0:
        return OK, x, P, 0.0
    zbar = np.empty(m)
    for i in range(m):
        per = periods[i]
        if per > 0.0:
            sn = 0.0
            cs = 0.0
            for j in range(N):
                sn += Wm[j] * np.sin(Zf[j, i] * (_TWO_PI / per))
                cs += Wm[j] * np.cos(Zf[j, i] * (_TWO_PI / per))
            zbar[i] = np.arctan2(sn, cs) * (per / _TWO_PI)
        else:
            acc = 0.0
            for j in range(N):
                acc += Wm[j] * Zf[j, i]
            zbar[i] = acc
    dZ = np.empty((N, q))
    nu = np.empty(q)
    Rq = np.empty((q, q))
    for a in range(q):
        i = idx[a]
        for j in range(N):
            dZ[j, a] = _wrap(Zf[j, i] - zbar[i], periods[i])
        nu[a] = _wrap(z[k, i] - zbar[i], periods[i])
        for b in range(q):
            Rq[a, b] = R[i, idx[b]]
    WdZ = Wc.reshape(N, 1) * dZ
    S = WdZ.T @ dZ + Rq
    C = (Wc.reshape(N, 1) * (X - x)).T @ dZ
    L = np.empty((q, q))
    if not _cholesky(S, L, q):
        return NOT_PD, x, P, 0.0
    K = np.empty((n, q))
    w = np.empty(q)
    ll = _gain_loglik(L, nu, C, K, w, n, q)
    x = x + K @ nu
    P = P - K @ S @ K.T
    _symmetrise(P)
    return OK, x, P, ll


@njit(cache=True, nogil=True)
def ukf_update_into(x, P, X, Zf, Wm, Wc, R, z, k, periods, x_out, P_out):
    """:func:`_ukf_update` into x_out, P_out with the finiteness checks: (status, loglik)."""
    x_out[:] = x
    P_out[:, :] = P
    if not (_finite(x, P) and np.isfinite(Zf.sum() + R.sum())):
        return DIVERGED, 0.0
    status, xu, Pu, ll = _ukf_update(x, P, X, Zf, Wm, Wc, R, z, k, periods)
    if status != OK:
        return status, 0.0
    x_out[:] = xu
    P_out[:, :] = Pu
    return (OK if _finite(xu, Pu) else DIVERGED), ll
