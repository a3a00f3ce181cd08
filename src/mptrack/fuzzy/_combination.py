"""Combination rules of Bouzera et al. (2017) section 3.3 beside the fuzzy one (eqs. 15-16).

For N local single-station solutions X_i, P_i = (I - K_i H_i) P^- with weights y_i >= 0:

- Proposition 3 (eq. 29, symmetric P^-): the fused covariance of eq. 16 written with the local
  covariances, P_est = sum_i w_i (P_i + P_i^T) + P^- (sum_i w_i^2 H_i^T S_i^-1 H_i) P^- - P^-,
  w_i = y_i / sum_j y_j;
- Proposition 4 (eq. 30, the first one): trace(P_est) = 2 sum_i w_i trace(P_i) + const, so the
  trace grows with every trace(P_i) (slope 2 w_i >= 0);
- the probabilistic rule (the second eq. 30, the paper's reference [39]): information-weighted
  fusion X = P sum_i P_i^-1 X_i, P = (sum_i P_i^-1)^-1, which ignores the weights y.
"""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result
from .._core.validation import as_array, as_vector, check_covariance
from ..errors import ParameterError, ShapeError, SingularMatrixError

__all__ = ["fused_covariance_prop3", "fused_covariance_trace", "probabilistic_fusion"]


def _weights(y, count: int) -> np.ndarray:
    y = as_vector("y", y, count, low=0.0)
    if not y.sum() > 0:
        raise ParameterError(f"y: weights must be finite, >= 0 and not all zero, got {y.tolist()}")
    y = y / y.max()                     # no overflow of the sum
    return y / y.sum()


def _local_terms(P_pred, P_local, H, S, y):
    """Validated (P_pred (n, n), P_local (N, n, n), H (N, m, n), S (N, m, m), w (N,)) and
    sum_i w_i^2 H_i^T S_i^-1 H_i."""
    P_local = as_array("P_local", P_local, ndim=3)
    N, n = P_local.shape[:2]
    P_local = as_array("P_local", P_local, shape=(N, n, n))
    P_pred = check_covariance("P_pred", P_pred, n)
    H = as_array("H", H, ndim=3)
    H = as_array("H", H, shape=(N, H.shape[1], n))
    S = as_array("S", S, shape=(N, H.shape[1], H.shape[1]))
    w = _weights(y, N)
    try:
        Sinv = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        raise SingularMatrixError("S: a local innovation covariance is singular") from None
    return P_pred, P_local, w, np.einsum("i,imn,imk,ikl->nl", w ** 2, H, Sinv, H)   # sum_i w_i^2 H^T S^-1 H


@finite_result("the fused covariance")
def fused_covariance_prop3(P_pred, P_local, H, S, y) -> np.ndarray:
    """The fused covariance by eq. 29 of Bouzera et al. 2017 (Proposition 3, with a symmetric P^-).

    Equals eq. 16 (tested).

    Parameters
    ----------
    P_pred : array_like, shape (n, n)
        The predicted covariance P^-.
    P_local : array_like, shape (N, n, n)
        The local (one-station) covariances.
    H : array_like, shape (N, m, n)
        Local measurement Jacobians.
    S : array_like, shape (N, m, m)
        Local innovation covariances.
    y : array_like, shape (N,)
        Weights.

    Returns
    -------
    ndarray, shape (n, n)

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    P_pred, P_local, w, info = _local_terms(P_pred, P_local, H, S, y)
    sym = np.einsum("i,inm->nm", w, P_local + np.swapaxes(P_local, 1, 2))
    return sym + P_pred @ info @ P_pred - P_pred


@finite_result("the fused covariance's trace")
def fused_covariance_trace(P_pred, P_local, H, S, y) -> float:
    """trace(P_est) by the first eq. 30 of Bouzera et al. 2017 (Proposition 4):
    2 sum_i w_i trace(P_i) + trace(P^- (sum_i w_i^2 H_i^T S_i^-1 H_i) P^-) - trace(P^-).

    Parameters
    ----------
    P_pred : array_like, shape (n, n)
        The predicted covariance P^-.
    P_local : array_like, shape (N, n, n)
        The local (one-station) covariances.
    H : array_like, shape (N, m, n)
        Local measurement Jacobians.
    S : array_like, shape (N, m, m)
        Local innovation covariances.
    y : array_like, shape (N,)
        Weights.

    Returns
    -------
    float

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    P_pred, P_local, w, info = _local_terms(P_pred, P_local, H, S, y)
    return float(2.0 * w @ np.trace(P_local, axis1=1, axis2=2) + np.trace(P_pred @ info @ P_pred)
                 - np.trace(P_pred))


@finite_result("the probabilistic fusion")
def probabilistic_fusion(X, P):
    """Probabilistic fusion (the second eq. 30 of Bouzera et al. 2017): P = (sum_i P_i^-1)^-1,
    x = P sum_i P_i^-1 x_i.

    Parameters
    ----------
    X : array_like, shape (N, n)
        The estimates.
    P : array_like, shape (N, n, n)
        Their covariances, positive definite.

    Returns
    -------
    x : ndarray, shape (n,)
    P : ndarray, shape (n, n)

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    X = as_array("X", X, ndim=2)
    if 0 in X.shape:
        raise ShapeError(f"X: expected N >= 1 local solutions of n >= 1 states, got shape {X.shape}")
    P = as_array("P", P, shape=X.shape + X.shape[-1:])
    try:
        info = np.linalg.inv(P)
        Pf = np.linalg.inv(info.sum(axis=0))
    except np.linalg.LinAlgError:
        raise ParameterError("P: the local covariances must be positive definite") from None
    return Pf @ np.einsum("imn,in->m", info, X), 0.5 * (Pf + Pf.T)
