"""The Lainiotis filter (Assimakis & Adam 2014, eqs. 5-7)."""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result
from .._core.validation import as_array, as_matrix, as_vector
from ..errors import ParameterError
from ..models import LinearGaussianModel
from ..result import FilterResult
from ..riccati import LainiotisParameters, lainiotis_parameters
from ._common import prepare_inputs
from ._kernels import lf_loop

__all__ = ["lainiotis_filter", "lainiotis_step"]


@finite_result("the Lainiotis step")
def lainiotis_step(lp: LainiotisParameters, F, Q, x, P, z, eye):
    """One Lainiotis filter iteration in readable NumPy (Assimakis & Adam 2014, eqs. 5-6).

    x(k+1/k+1) = Kn z + Fn [I + P On]^-1 [P Km z + x],  P(k+1/k+1) = Pn + Fn [I + P On]^-1 P Fn^T;
    a missing (NaN) measurement only predicts.  :func:`lainiotis_filter` runs it compiled.

    Parameters
    ----------
    lp : LainiotisParameters
        From :func:`mptrack.riccati.lainiotis_parameters`.
    F, Q : array_like, shape (n, n)
        Transition matrix and process noise (for a missing measurement's prediction).
    x : array_like, shape (n,)
        x(k/k).
    P : array_like, shape (n, n)
        P(k/k).
    z : array_like, shape (m,)
        z(k+1).
    eye : ndarray, shape (n, n)
        The identity (passed in so that a loop allocates it once).

    Returns
    -------
    x, P : ndarray
        x(k+1/k+1), P(k+1/k+1).

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] D. G. Lainiotis, "Partitioned linear estimation algorithms: discrete case", IEEE Transactions on
           Automatic Control, vol. 20, no. 2, pp. 255–257, 1975.
    """
    if not isinstance(lp, LainiotisParameters):
        raise ParameterError(f"lp: expected LainiotisParameters, got {type(lp).__name__}")
    n, m = lp.Kn.shape
    F, Q, P, eye = (as_matrix(name, v, n, n) for name, v in (("F", F), ("Q", Q), ("P", P), ("eye", eye)))
    x, z = as_vector("x", x, n), as_array("z", z, shape=(m,), allow_nan=True)
    if np.isnan(z).any():
        P_new = F @ P @ F.T + Q
        return F @ x, 0.5 * (P_new + P_new.T)
    rhs = np.column_stack((P @ (lp.Km @ z) + x, P))
    sol = lp.Fn @ np.linalg.solve(eye + P @ lp.On, rhs)
    x_new = lp.Kn @ z + sol[:, 0]
    P_new = lp.Pn + sol[:, 1:] @ lp.Fn.T
    return x_new, 0.5 * (P_new + P_new.T)


@finite_result("the Lainiotis filter")
def lainiotis_filter(model: LinearGaussianModel, z, x0=None, P0=None, *,
                     params: LainiotisParameters | None = None) -> FilterResult:
    """Lainiotis filter (Assimakis & Adam 2014, eqs. 5-7): the KF's estimates by another algebra.

    Measurements with any NaN component only predict (the LF has no partial update).

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    z : array_like, shape (T, m)
        Measurements z(1..T); NaN components are missing (a NaN row only predicts).
    x0 : array_like, shape (n,), optional
        The prior x(0/0) (default zeros).
    P0 : array_like, shape (n, n)
        The prior covariance P(0/0), required.
    params : LainiotisParameters, optional
        The off-line parameters (:func:`mptrack.riccati.lainiotis_parameters`), computed when not given.

    Returns
    -------
    FilterResult
        Filtered means and covariances (no prediction or innovation fields: the algebra has none).

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] D. G. Lainiotis, "Partitioned linear estimation algorithms: discrete case", IEEE Transactions on
           Automatic Control, vol. 20, no. 2, pp. 255–257, 1975.
    """
    z, x, P, _ = prepare_inputs(model, z, x0, P0)
    lp = lainiotis_parameters(model) if params is None else params
    T, n = z.shape[0], model.n
    xs = np.empty((T, n))
    Ps = np.empty((T, n, n))
    lf_loop(model.F, model.Q, lp.Kn, lp.Km, lp.Pn, lp.Fn, lp.On, z, x, P, xs, Ps)
    return FilterResult(x=xs, P=Ps, method="LF")
