"""The time-invariant Kalman filter (seed 000 eq. 4)."""

from __future__ import annotations

import numpy as np

from .._validation import as_array, as_matrix, as_vector, finite_result
from ..errors import ShapeError
from ..models import LinearGaussianModel
from ._common import prepare_inputs
from ._kernels import kf_loop
from ._result import FilterResult

__all__ = ["kalman_filter", "kalman_step"]

_LOG2PI = np.log(2.0 * np.pi)


@finite_result("the Kalman step")
def kalman_step(F, H, Q, R, x, P, z, joseph: bool = False):
    """One KF iteration: from x(k/k), P(k/k) and z(k+1) to the next filtered pair.

    The readable NumPy form of the equations; :func:`kalman_filter` runs the
    same equations in a compiled loop (tests check that the two agree).

    Returns (x_filt, P_filt, x_pred, P_pred, loglik_increment).  Components of
    z that are NaN are not used; a fully missing z only predicts.
    """
    F = as_matrix("F", F)
    n = F.shape[1]
    x, P, Q = as_vector("x", x, n), as_matrix("P", P, n, n), as_matrix("Q", Q, n, n)
    if F.shape != (n, n):
        raise ShapeError(f"F: expected a square matrix, got shape {F.shape}")
    H = as_matrix("H", H, None, n)
    R, z = as_matrix("R", R, H.shape[0], H.shape[0]), as_array("z", z, shape=(H.shape[0],), allow_nan=True)
    x_pred = F @ x
    P_pred = F @ P @ F.T + Q
    ok = ~np.isnan(z)
    if not ok.any():
        return x_pred, P_pred, x_pred, P_pred, 0.0
    if not ok.all():
        H, R, z = H[ok], R[np.ix_(ok, ok)], z[ok]
    PHt = P_pred @ H.T
    S = H @ PHt + R
    S_inv = np.linalg.inv(S)
    K = PHt @ S_inv
    innov = z - H @ x_pred
    x_filt = x_pred + K @ innov
    if joseph:
        IKH = np.eye(len(x)) - K @ H
        P_filt = IKH @ P_pred @ IKH.T + K @ R @ K.T
    else:
        P_filt = P_pred - K @ PHt.T
    P_filt = 0.5 * (P_filt + P_filt.T)
    _, logdet = np.linalg.slogdet(S)
    ll = -0.5 * (innov @ S_inv @ innov + logdet + len(innov) * _LOG2PI)
    return x_filt, P_filt, x_pred, P_pred, ll


@finite_result("the Kalman filter")
def kalman_filter(model: LinearGaussianModel, z, x0=None, P0=None, *, joseph: bool = False) -> FilterResult:
    """Kalman filter with the per-step Riccati recursion (seed 000 eq. 4).

    model   a LinearGaussianModel
    z       (T, m) measurements z(1..T); rows with NaN are treated as missing
            (NaN components are skipped, a full NaN row only predicts)
    x0, P0  the prior x(0/0), P(0/0) (default zeros, as in the papers' example)
    joseph  use the Joseph form (I-KH) P (I-KH)^T + K R K^T for P(k/k)

    Returns a FilterResult with filtered and predicted means/covariances and
    the measurement log-likelihood.  The time loop is compiled (numba); see
    :func:`kalman_step` for the same equations step by step in NumPy.
    """
    z, x, P, _ = prepare_inputs(model, z, x0, P0)
    T, n = z.shape[0], model.n
    xs = np.empty((T, n))
    Ps = np.empty((T, n, n))
    xp = np.empty((T, n))
    Pp = np.empty((T, n, n))
    loglik = kf_loop(model.F, model.H, model.Q, model.R, z, x, P, bool(joseph), xs, Ps, xp, Pp)
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method="KF")
