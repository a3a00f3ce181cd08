"""Accuracy metrics: position errors, RMSE, and the posterior Cramér–Rao bound (PCRB).

PCRB (Tichavský, Muravchik & Nehorai 1998, IEEE Trans. Signal Process. 46(5), eq. 21):
for x(k+1) = F x(k) + w, w ~ N(0, Q) and measurements with Fisher information
I_z(k) = E[H(k)^T R^{-1} H(k)] (H the measurement Jacobian at the true state),

    J(k+1) = D22 - D21 (J(k) + D11)^{-1} D12,   D11 = F^T Q^{-1} F,  D12 = D21^T = -F^T Q^{-1},
                                               D22 = Q^{-1} + I_z(k+1),     J(0) = P0^{-1},

and any unbiased estimator has E[(x̂ - x)(x̂ - x)^T] >= J(k)^{-1}.  By the matrix
inversion lemma this is J(k+1) = (Q + F J(k)^{-1} F^T)^{-1} + I_z(k+1), the
information form of the Kalman covariance recursion, which we use (it also
allows a singular Q).
"""

from __future__ import annotations

import numpy as np

from ._core.finiteness import finite_result, renamed
from ._core.validation import as_array, as_matrix, broadcast_shape, check_allocation, check_covariance, check_int
from .errors import ParameterError, ShapeError, SingularMatrixError

__all__ = ["position_error", "rmse", "nees", "pcrb", "pcrb_tichavsky", "range_fisher_information", "pcrb_ranges"]


@finite_result("the position error")
def position_error(x_est, truth, dims: int | None = None) -> np.ndarray:
    """Euclidean position error ||x_est - x|| per time step (Bouzera et al. 2017, eq. 25).

    Parameters
    ----------
    x_est, truth : array_like, shape (..., T, n)
        Estimates and true states.
    dims : int, optional
        Number of leading state components that are the position (default: all of truth's).

    Returns
    -------
    ndarray, shape (..., T)

    References
    ----------
    .. [1] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    x_est, truth = _pair(x_est, truth)
    d = truth.shape[-1] if dims is None else check_int("dims", dims, minimum=1, maximum=truth.shape[-1])
    with np.errstate(over="ignore"):   # an overflow is reported by finite_result
        return np.linalg.norm(x_est[..., :d] - truth[..., :d], axis=-1)


def _pair(x_est, truth) -> tuple[np.ndarray, np.ndarray]:
    """Estimates and truth: finite (NaN allowed in the estimate, a missing value) with states on the
    last axis, broadcasting together."""
    x_est = as_array("x_est", x_est, allow_nan=True)
    truth = as_array("truth", truth)
    for name, arr in (("x_est", x_est), ("truth", truth)):
        if arr.ndim == 0 or 0 in arr.shape:
            raise ShapeError(f"{name}: expected states on the last axis (..., n), got shape {arr.shape}")
    if x_est.shape[-1] < truth.shape[-1]:
        raise ShapeError(f"x_est: expected at least {truth.shape[-1]} state components (as truth), "
                         f"got shape {x_est.shape}")
    broadcast_shape(x_est=x_est[..., 0], truth=truth[..., 0])
    return x_est, truth


@finite_result("the RMSE")
def rmse(x_est, truth, dims: int | None = None, axis: int = 0) -> np.ndarray:
    """Root-mean-square position error over Monte-Carlo runs.

    Parameters
    ----------
    x_est, truth : array_like, shape (B, T, n)
        Estimates and true states of B runs.
    dims : int, optional
        Number of leading state components that are the position.
    axis : int, optional
        The axis of the runs.

    Returns
    -------
    ndarray, shape (T,)
    """
    e = position_error(x_est, truth, dims)
    if e.ndim == 0:
        raise ShapeError(f"x_est: expected positions of shape (..., n), one row per step, got shape "
                         f"{np.shape(x_est)}")
    if not isinstance(axis, (int, np.integer)) or not -e.ndim <= axis < e.ndim:
        raise ParameterError(f"axis: expected an integer in [-{e.ndim}, {e.ndim}) (the error has shape "
                             f"{e.shape}), got {axis!r}")
    with np.errstate(over="ignore"):   # an overflow is reported by finite_result
        return np.sqrt(np.mean(e ** 2, axis=axis))


@finite_result("the NEES")
def nees(x_est, P, truth) -> np.ndarray:
    """Normalised estimation error squared (x_est - x)^T P^-1 (x_est - x) per step.

    For a consistent filter its mean over runs is the state dimension n (chi-square with n degrees of
    freedom per run; Bar-Shalom et al. 2001, sec. 5.4).

    Parameters
    ----------
    x_est : array_like, shape (..., T, n)
    P : array_like, shape (..., T, n, n)
        The reported covariances.
    truth : array_like, shape (..., T, n)

    Returns
    -------
    ndarray, shape (..., T)

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    """
    x_est, truth = _pair(x_est, truth)
    if x_est.shape[-1] != truth.shape[-1]:
        raise ShapeError(f"x_est: expected {truth.shape[-1]} state components (as truth), got shape {x_est.shape}")
    n = truth.shape[-1]
    P = as_array("P", P)
    if P.ndim < 2 or P.shape[-2:] != (n, n):
        raise ShapeError(f"P: expected shape (..., {n}, {n}), got shape {P.shape}")
    broadcast_shape(x_est=x_est[..., 0], P=P[..., 0, 0])
    e = x_est - truth
    try:
        return np.einsum("...i,...i->...", e, np.linalg.solve(P, e[..., None])[..., 0])
    except np.linalg.LinAlgError:
        raise SingularMatrixError("P: a covariance is singular; the NEES needs P^-1") from None


@finite_result("the PCRB")
def pcrb(F, Q, P0, info) -> np.ndarray:
    """Posterior Cramér-Rao bound J(k)^-1, k = 1..T, for linear-Gaussian dynamics (the Kalman recursion
    in information form: Q may be singular).

    Parameters
    ----------
    F, Q : array_like, shape (n, n)
        Transition matrix and process noise.
    P0 : array_like, shape (n, n)
        Prior covariance, positive definite.
    info : array_like, shape (T, n, n)
        The measurement Fisher information I_z(k).

    Returns
    -------
    ndarray, shape (T, n, n)

    References
    ----------
    .. [1] P. Tichavský, C. H. Muravchik and A. Nehorai, "Posterior Cramér–Rao bounds for discrete-time
           nonlinear filtering", IEEE Transactions on Signal Processing, vol. 46, no. 5, pp. 1386–1396, 1998.
           doi:10.1109/78.668800
    """
    F, Q, P, info = _pcrb_inputs(F, Q, P0, info, definite_Q=False)
    out = np.empty_like(info)
    for k in range(info.shape[0]):
        M = F @ P @ F.T + Q
        try:
            J = np.linalg.inv(M) + info[k]
            P = np.linalg.inv(J)
        except np.linalg.LinAlgError:
            raise SingularMatrixError(f"Q: the predicted covariance F P F^T + Q or the information J is singular "
                                      f"at step {k}; the bound needs their inverses") from None
        out[k] = 0.5 * (P + P.T)
    return out


def _pcrb_inputs(F, Q, P0, info, *, definite_Q: bool):
    F = as_matrix("F", F)
    n = F.shape[0]
    if F.shape != (n, n):
        raise ShapeError(f"F: expected a square matrix, got shape {F.shape}")
    Q = check_covariance("Q", Q, n, definite=definite_Q)
    P = check_covariance("P0", P0, n, definite=True)
    info = as_array("info", info, ndim=3)
    if info.shape[1:] != (n, n) or info.shape[0] == 0:
        raise ShapeError(f"info: expected shape (T, {n}, {n}) with T >= 1, got {info.shape}")
    return F, Q, P, info


@finite_result("the PCRB")
def pcrb_tichavsky(F, Q, P0, info) -> np.ndarray:
    """The same bound by Tichavský's D11/D12/D22 recursion (Q invertible); a cross-check of :func:`pcrb`.

    Parameters
    ----------
    F, Q : array_like, shape (n, n)
        Transition matrix and process noise.
    P0 : array_like, shape (n, n)
        Prior covariance, positive definite.
    info : array_like, shape (T, n, n)
        The measurement Fisher information I_z(k).

    Returns
    -------
    ndarray, shape (T, n, n)

    References
    ----------
    .. [1] P. Tichavský, C. H. Muravchik and A. Nehorai, "Posterior Cramér–Rao bounds for discrete-time
           nonlinear filtering", IEEE Transactions on Signal Processing, vol. 46, no. 5, pp. 1386–1396, 1998.
           doi:10.1109/78.668800
    """
    F, Q, P0, info = _pcrb_inputs(F, Q, P0, info, definite_Q=True)
    try:
        J = np.linalg.inv(P0)
        Qi = np.linalg.inv(Q)
    except np.linalg.LinAlgError:
        raise SingularMatrixError("Q: Q and P0 must be invertible (numerically)") from None
    D11, D12, D22_0 = F.T @ Qi @ F, -F.T @ Qi, Qi
    out = np.empty_like(info)
    for k in range(info.shape[0]):
        try:
            J = D22_0 + info[k] - D12.T @ np.linalg.solve(J + D11, D12)
            out[k] = np.linalg.inv(J)
        except np.linalg.LinAlgError:
            raise SingularMatrixError(f"Q: the information J at step {k} is singular") from None
    return out


@finite_result("the range Fisher information")
def range_fisher_information(positions, stations, R, n: int | None = None) -> np.ndarray:
    """Fisher information of ranges at the true positions: sum_i H_i^T H_i / R_ii.

    Parameters
    ----------
    positions : array_like, shape (T, d) or (B, T, d)
        True positions (a batch: the expectation is the mean over runs).
    stations : array_like, shape (m, d)
    R : float or array_like, shape (m,)
        Range variances, > 0.
    n : int, optional
        State size (the position first; default d).

    Returns
    -------
    ndarray, shape (T, n, n)

    References
    ----------
    .. [1] P. Tichavský, C. H. Muravchik and A. Nehorai, "Posterior Cramér–Rao bounds for discrete-time
           nonlinear filtering", IEEE Transactions on Signal Processing, vol. 46, no. 5, pp. 1386–1396, 1998.
           doi:10.1109/78.668800
    """
    st = as_matrix("stations", stations)
    d = st.shape[1]
    if d not in (2, 3):
        raise ShapeError(f"stations: expected shape (m, 2) or (m, 3), got {st.shape}")
    pos = as_array("positions", positions)
    if pos.ndim not in (2, 3) or pos.shape[-1] != d or 0 in pos.shape:
        raise ShapeError(f"positions: expected shape (T, {d}) or (B, T, {d}) (as stations), got {pos.shape}")
    r = as_array("R", R)
    if r.shape not in ((), (st.shape[0],)) or not np.all(r > 0):
        raise ParameterError(f"R: expected a variance > 0 or one per station ({st.shape[0]},), got {R!r}")
    n = d if n is None else check_int("n", n, minimum=d)
    check_allocation("positions", f"{pos.size // d} positions", 8.0 * pos.size * st.shape[0] * 2 + 8.0 * pos.size * n)
    diff = pos[..., None, :] - st
    with np.errstate(over="ignore", invalid="ignore"):
        rng = np.linalg.norm(diff, axis=-1)
    if np.any(rng <= 0):
        raise SingularMatrixError("positions: a position coincides with a station; range information is undefined")
    u = diff / rng[..., None]
    r = np.broadcast_to(r, (st.shape[0],))
    info_pos = np.einsum("...mi,...mj,m->...ij", u, u, 1.0 / r)
    if info_pos.ndim == 4:
        info_pos = info_pos.mean(axis=0)
    info = np.zeros(info_pos.shape[:-2] + (n, n))
    info[..., :d, :d] = info_pos
    return info


@finite_result("the PCRB")
def pcrb_ranges(truth, stations, P0, Q, R, F=None) -> np.ndarray:
    """PCRB of the position RMSE from ranges: sqrt(trace of the position block of J^-1) per step.

    Parameters
    ----------
    truth : array_like, shape (T, d) or (B, T, d)
        True positions.
    stations : array_like, shape (m, d)
    P0, Q : array_like, shape (n, n)
    R : float or array_like, shape (m,)
        Range variances.
    F : array_like, shape (n, n), optional
        Transition matrix (default the identity: the random walk of Bouzera et al. 2017, eq. 1).

    Returns
    -------
    ndarray, shape (T,)

    References
    ----------
    .. [1] P. Tichavský, C. H. Muravchik and A. Nehorai, "Posterior Cramér–Rao bounds for discrete-time
           nonlinear filtering", IEEE Transactions on Signal Processing, vol. 46, no. 5, pp. 1386–1396, 1998.
           doi:10.1109/78.668800
    .. [2] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    Q = as_matrix("Q", Q)
    n = Q.shape[0]
    F = np.eye(n) if F is None else F
    with renamed(positions="truth", n="Q"):          # n is the size of Q
        info = range_fisher_information(truth, stations, R, n)
    bound = pcrb(F, Q, P0, info)
    d = np.shape(stations)[1]
    return np.sqrt(np.trace(bound[:, :d, :d], axis1=1, axis2=2))
