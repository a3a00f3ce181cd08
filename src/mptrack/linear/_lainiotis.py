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
    """One LF iteration (eqs. 5-6); a missing (NaN) measurement only predicts.

    The readable NumPy form; :func:`lainiotis_filter` runs it compiled.

    x(k+1/k+1) = Kn z + Fn [I + P On]^{-1} [P Km z + x]
    P(k+1/k+1) = Pn + Fn [I + P On]^{-1} P Fn^T

    lp from :func:`mptrack.riccati.lainiotis_parameters`; F, Q (n, n); x (n,); P (n, n); z (m,); eye the
    (n, n) identity.

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
    """Lainiotis filter (Assimakis & Adam 2014, eqs. 5-7): same estimates as the KF, other algebra.

    ``params`` are the off-line Lainiotis parameters; computed from ``model``
    when not given.  Measurements with any NaN component only predict (the LF
    has no partial update).  Returns filtered means and covariances.

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
