"""The scaled unscented transform (Julier 2002): its weights, the sigma points of a Gaussian and their
validation.  Shared by the UKF of mptrack.nonlinear (any NonlinearModel), the continuous-discrete UKF and
the FEM grid filter of mptrack.continuous; ``sigma_points`` is public as
:func:`mptrack.nonlinear.sigma_points`."""

from __future__ import annotations

import numpy as np

from .finiteness import finite_result
from .validation import as_real, as_vector, check_covariance, check_positive
from ..errors import NotPositiveDefiniteError, ParameterError

__all__ = ["weights", "covariance_sqrt", "check_unscented", "sigma_points", "sigma_points_unchecked"]


def weights(n: int, alpha: float, beta: float, kappa: float):
    """(n + λ, Wm (2n+1,), Wc (2n+1,)) of the scaled unscented transform (validated parameters)."""
    lam = alpha * alpha * (n + kappa) - n
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = Wm[0] + 1.0 - alpha * alpha + beta
    return n + lam, Wm, Wc


def covariance_sqrt(P: np.ndarray, what: str) -> np.ndarray:
    """A square root S (S S^T = P) of a covariance: its Cholesky factor, or for a semi-definite P the
    eigenvalue root; a P that lost positive semi-definiteness is a NotPositiveDefiniteError naming ``what``."""
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(0.5 * (P + P.T))
        if w[0] < -1e-9 * max(abs(w[-1]), 1e-300):
            raise NotPositiveDefiniteError(f"{what}: covariance lost positive semi-definiteness "
                                           f"(smallest eigenvalue {w[0]:.3g})") from None
        return V * np.sqrt(np.clip(w, 0.0, None))


def check_unscented(n: int, alpha, beta, kappa) -> dict:
    """Validated scaled-unscented-transform parameters: α > 0, β >= 0, n + κ > 0 (so (n + λ) > 0)."""
    alpha = check_positive("alpha", alpha)
    beta = check_positive("beta", beta, allow_zero=True)
    kappa = as_real("kappa", kappa)
    if n + kappa <= 0:
        raise ParameterError(f"kappa: expected a finite number with n + kappa > 0 (n = {n}), got {kappa!r}")
    return {"alpha": alpha, "beta": beta, "kappa": kappa}


@finite_result("the sigma points")
def sigma_points(m: np.ndarray, P: np.ndarray, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0):
    """The 2n+1 scaled sigma points of N(m, P) and their weights.

    Parameters
    ----------
    m : array_like, shape (n,)
        The mean.
    P : array_like, shape (n, n)
        The covariance, positive semi-definite.
    alpha, beta, kappa : float, optional
        Scaled unscented transform parameters; the defaults (1, 2, 0) keep every weight non-negative for
        every n, so the propagated covariance stays positive semi-definite.

    Returns
    -------
    X : ndarray, shape (2n+1, n)
        The points.
    Wm, Wc : ndarray, shape (2n+1,)
        Mean and covariance weights.

    References
    ----------
    .. [1] S. J. Julier, "The scaled unscented transformation", Proceedings of the 2002 American Control
           Conference, vol. 6, pp. 4555–4559, 2002. doi:10.1109/ACC.2002.1025369
    """
    m = as_vector("m", m)
    P = check_covariance("P", P, m.shape[0])
    return sigma_points_unchecked(m, P, **check_unscented(m.shape[0], alpha, beta, kappa))


def sigma_points_unchecked(m: np.ndarray, P: np.ndarray, *, alpha: float, beta: float, kappa: float):
    """:func:`sigma_points` of validated arguments (the filters' inner step)."""
    n = m.shape[0]
    c, Wm, Wc = weights(n, alpha, beta, kappa)
    S = covariance_sqrt(c * P, "P")
    X = np.empty((2 * n + 1, n))
    X[0] = m
    X[1:n + 1] = m + S.T
    X[n + 1:] = m - S.T
    return X, Wm, Wc
