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

The update itself (innovation, Cholesky factor, gain, Joseph or standard form, log-likelihood) is the
one compiled Kalman update of :mod:`mptrack._core.kalman`; this module adds the sigma points, the
unscented moments and the ``*_into`` entry points with their finiteness checks.  NaN components of z
are skipped.  A core reports a problem by a status code instead of raising: NOT_PD (an innovation
covariance without a Cholesky factor), DIVERGED (a non-finite input or result).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.kalman import (
    DIVERGED,
    NOT_PD,
    OK,
    cholesky,
    cov_predict,
    finite,
    record_update,
    symmetrise,
    unscented_update,
    update,
    workspace,
)

__all__ = ["ekf_predict_into", "ekf_update_into", "ekf_predict_tracks", "ekf_update_tracks", "sigma_into",
           "unscented_moments_into", "ukf_update_into", "OK", "NOT_PD", "DIVERGED"]


# ---------------------------------------------------------------- EKF
@njit(cache=True, nogil=True)
def ekf_predict_into(F, P, Q, P_out):
    """P_out = F P F^T + Q."""
    n = P.shape[0]
    P_out[:, :] = P
    cov_predict(F, Q, P_out, np.empty((n, n)))


@njit(cache=True, nogil=True)
def ekf_update_into(x, P, H, hx, R, z, k, periods, x_out, P_out, nus, Ss, nis, row):
    """One EKF update of x, P with row k of z into x_out, P_out, its innovation, S and NIS into row
    ``row`` of nus, Ss, nis (row < 0: not recorded): (status, loglik); DIVERGED for non-finite input
    or output."""
    x_out[:] = x
    P_out[:, :] = P
    if not (finite(x, P) and np.isfinite(H.sum() + hx.sum() + R.sum())):
        return DIVERGED, 0.0
    ws = workspace(x.shape[0], z.shape[1])
    status, ll = update(x_out, P_out, H, hx, R, z, k, periods, True, ws)
    if status == OK and not finite(x_out, P_out):
        status = DIVERGED
    if status == OK:
        record_update(ws, z, k, nus, Ss, nis, row)
    return status, ll


@njit(cache=True, nogil=True)
def ekf_predict_tracks(F, P, Q, Pp):
    """P(k/k-1) = F P F^T + Q of every track b (F (B, n, n), P (B, n, n)) into Pp (B, n, n) and P."""
    n = P.shape[1]
    A = np.empty((n, n))
    for b in range(P.shape[0]):
        cov_predict(F[b], Q, P[b], A)
        Pp[b] = P[b]


@njit(cache=True, nogil=True)
def ekf_update_tracks(x, P, H, hx, R, z, k, periods, xs, Ps, nus, Ss, nis, loglik):
    """The EKF update (Joseph form) of every track b with row k of z[b] (H (B, m, n), hx (B, m) at the
    prediction x, P, updated in place and copied into xs[b, k], Ps[b, k]); innovation, S and NIS into
    row k of nus[b], Ss[b], nis[b], the log-likelihood added to loglik[b].  Returns (status, b): the
    first track whose update failed (NOT_PD, DIVERGED), or (OK, -1)."""
    ws = workspace(x.shape[1], z.shape[2])
    for b in range(x.shape[0]):
        if not (finite(x[b], P[b]) and np.isfinite(H[b].sum() + hx[b].sum())):
            return DIVERGED, b
        status, ll = update(x[b], P[b], H[b], hx[b], R, z[b], k, periods, True, ws)
        if status == OK and not finite(x[b], P[b]):
            status = DIVERGED
        if status != OK:
            return status, b
        record_update(ws, z[b], k, nus[b], Ss[b], nis[b], k)
        xs[b, k] = x[b]
        Ps[b, k] = P[b]
        loglik[b] += ll
    return OK, -1


# ---------------------------------------------------------------- UKF
@njit(cache=True, nogil=True)
def _sigma(x, P, c, X):
    """The 2n+1 sigma points of N(x, P) into X; False when c P has no Cholesky factor."""
    n = x.shape[0]
    L = np.empty((n, n))
    if not cholesky(c * P, L, n):
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
    symmetrise(P)
    return x, P


@njit(cache=True, nogil=True)
def unscented_moments_into(Y, Wm, Wc, Q, x_out, P_out):
    """:func:`unscented_moments` into x_out, P_out."""
    x, P = unscented_moments(Y, Wm, Wc, Q)
    x_out[:] = x
    P_out[:, :] = P


@njit(cache=True, nogil=True)
def ukf_update_into(x, P, X, Zf, Wm, Wc, R, z, k, periods, x_out, P_out, nus, Ss, nis, row):
    """:func:`mptrack._core.kalman.unscented_update` into x_out, P_out (and row ``row`` of nus, Ss, nis)
    with the finiteness checks: (status, loglik)."""
    x_out[:] = x
    P_out[:, :] = P
    if not (finite(x, P) and np.isfinite(Zf.sum() + R.sum())):
        return DIVERGED, 0.0
    status, xu, Pu, ll = unscented_update(x, P, X, Zf, Wm, Wc, R, z, k, periods, nus, Ss, nis, row)
    if status != OK:
        return status, 0.0
    x_out[:] = xu
    P_out[:, :] = Pu
    return (OK if finite(xu, Pu) else DIVERGED), ll
