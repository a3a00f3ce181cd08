"""The Lainiotis parameters (Assimakis & Adam 2014, eq. 7), shared by the LF and the RELF."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SingularMatrixError
from ..models import LinearGaussianModel, require_model

__all__ = ["LainiotisParameters", "lainiotis_parameters"]


@dataclass(frozen=True, eq=False)
class LainiotisParameters:
    """Off-line quantities of the Lainiotis filter (Assimakis & Adam 2014, eq. 7).

    A  = [H Q H^T + R]^{-1}     (Q is the papers' G Q G^T)
    Kn = Q H^T A,   Km = F^T H^T A,   Pn = Q - Kn H Q,
    Fn = F - Kn H F,   On = F^T H^T A H F.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] D. G. Lainiotis, "Partitioned linear estimation algorithms: discrete case", IEEE Transactions on
           Automatic Control, vol. 20, no. 2, pp. 255–257, 1975.
    """

    A: np.ndarray
    Kn: np.ndarray
    Km: np.ndarray
    Pn: np.ndarray
    Fn: np.ndarray
    On: np.ndarray


def lainiotis_parameters(model: LinearGaussianModel) -> LainiotisParameters:
    """The off-line parameters of the Lainiotis filter (Assimakis & Adam 2014, eq. 7).

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).

    Returns
    -------
    LainiotisParameters
        Pn, Kn, Km, Fn, On of the model.

    Raises
    ------
    SingularMatrixError
        A matrix the parameters invert is singular.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] D. G. Lainiotis, "Partitioned linear estimation algorithms: discrete case", IEEE Transactions on
           Automatic Control, vol. 20, no. 2, pp. 255–257, 1975.
    """
    F, H, Q, R = (require_model(model).F, model.H, model.Q, model.R)
    S = H @ Q @ H.T + R
    try:
        A = np.linalg.inv(S)
    except np.linalg.LinAlgError:  # pragma: no cover - R is validated positive definite
        raise SingularMatrixError("model: H Q H^T + R is singular") from None
    A = 0.5 * (A + A.T)
    Kn = Q @ H.T @ A
    Km = F.T @ H.T @ A
    Pn = Q - Kn @ H @ Q
    Pn = 0.5 * (Pn + Pn.T)
    Fn = F - Kn @ H @ F
    On = F.T @ H.T @ A @ H @ F
    On = 0.5 * (On + On.T)
    return LainiotisParameters(A=A, Kn=Kn, Km=Km, Pn=Pn, Fn=Fn, On=On)
