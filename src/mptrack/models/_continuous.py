"""Continuous-time linear motion models and their exact discretisation.

A continuous-time linear time-invariant (LTI) model driven by white noise,

    dx = Phi x dt + L dbeta,     E[dbeta dbeta^T] = Qc dt,
    z(k) = H x(t_k) + v(k),      v(k) ~ N(0, R),

sampled every dt seconds has the exact discrete transition (Assimakis et al. 2016, sec. 2)

    F = e^{Phi dt},      Q = int_0^dt e^{Phi s} L Qc L^T e^{Phi^T s} ds,

which :func:`van_loan` computes with one matrix exponential (Van Loan 1978,
"Computing integrals involving the matrix exponential", IEEE TAC 23(3)).
The constant-velocity (CV) and constant-acceleration (CA) models of Assimakis et al. 2016
(eqs. 5-6) are special cases; their closed forms are what this general method
gives.  The *discrete white-noise* variants (Q = q G G^T, the noise a
piecewise-constant acceleration or acceleration increment per sample; seeds
000/002 use the CV one) are a different model and carry that in their names.

Multi-axis models are block-diagonal with the state ordered axis by axis,
``[s_x, v_x, (a_x,) s_y, v_y, (a_y,) ...]``, as :func:`stack_axes` orders it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .._core.finiteness import derived_from, finite_result, renamed
from .._core.validation import (
    as_matrix,
    as_vector,
    check_allocation,
    check_covariance,
    check_int,
    check_positive,
    frozen,
)
from .._core.van_loan import intervals_unchecked, van_loan_unchecked
from ..errors import ParameterError, ShapeError
from ._linear import LinearGaussianModel, require_model, stack_axes

__all__ = [
    "ContinuousLinearModel",
    "van_loan",
    "discretize",
    "constant_velocity_continuous",
    "constant_acceleration_continuous",
    "constant_velocity",
    "constant_acceleration",
    "cv_discrete_white_noise",
    "ca_discrete_white_noise",
]


@dataclass(frozen=True, eq=False)
class ContinuousLinearModel:
    """A validated, immutable continuous-time LTI model (Assimakis et al. 2016, eqs. 1-2).

    Phi  (n, n)  drift matrix of dx = Phi x dt + L dbeta
    L    (n, p)  noise gain (the paper's G)
    Qc   (p, p)  spectral density of the white noise dbeta/dt (units of x^2 per
                 second, per unit of L); the paper's sigma_q^2
    H    (m, n)  measurement matrix of the sampled measurements z(k) = H x(t_k) + v(k)
    R    (m, m)  covariance of the sampled measurement noise v(k) (not a density)

    ``discretize(dt)`` gives the exact :class:`LinearGaussianModel` for a
    sampling interval of ``dt`` seconds.

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    """

    Phi: np.ndarray
    L: np.ndarray
    Qc: np.ndarray
    H: np.ndarray
    R: np.ndarray
    name: str = field(default="", kw_only=True)

    def __post_init__(self) -> None:
        Phi = as_matrix("Phi", self.Phi)
        n = Phi.shape[0]
        if Phi.shape != (n, n):
            raise ShapeError(f"Phi: expected a square matrix, got shape {Phi.shape}")
        L = as_matrix("L", self.L, n, None)
        Qc = check_covariance("Qc", self.Qc, L.shape[1])
        H = as_matrix("H", self.H, None, n)
        R = check_covariance("R", self.R, H.shape[0], definite=True)
        for attr, value in (("Phi", Phi), ("L", L), ("Qc", Qc), ("H", H), ("R", R)):
            object.__setattr__(self, attr, frozen(value))

    @property
    def n(self) -> int:
        """State dimension."""
        return self.Phi.shape[0]

    @property
    def m(self) -> int:
        """Measurement dimension."""
        return self.H.shape[0]

    def discretize(self, dt: float) -> LinearGaussianModel:
        """The exact discrete model for sampling interval ``dt`` seconds (see :func:`discretize`)."""
        return discretize(self, dt)

    def __repr__(self) -> str:
        label = f" {self.name!r}" if self.name else ""
        return f"<ContinuousLinearModel{label} n={self.n} m={self.m}>"


def van_loan(Phi, L, Qc, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation (F, Q) of dx = Phi x dt + L dbeta over an interval (Van Loan's method).

    With M = [[-Phi, L Qc L^T], [0, Phi^T]] dt and e^M = [[., E12], [0, E22]]: F = E22^T = e^{Phi dt} and
    Q = F E12 = int_0^dt e^{Phi s} L Qc L^T e^{Phi^T s} ds.

    Parameters
    ----------
    Phi : array_like, shape (n, n)
        Drift matrix of the continuous model.
    L : array_like, shape (n, p)
        Noise gain.
    Qc : array_like, shape (p, p)
        Spectral density of the white noise beta, symmetric positive semi-definite.
    dt : float
        The interval (s), >= 0; ``dt = 0`` gives F = I, Q = 0.

    Returns
    -------
    F, Q : ndarray, shape (n, n)
        Transition matrix and process-noise covariance over ``dt``.

    Raises
    ------
    ShapeError
        The matrices' sizes disagree.
    NonFiniteError
        The exponential overflows (an interval too long for the model).

    References
    ----------
    .. [1] C. F. Van Loan, "Computing integrals involving the matrix exponential", IEEE Transactions on
           Automatic Control, vol. 23, no. 3, pp. 395–404, 1978. doi:10.1109/TAC.1978.1101743
    """
    Phi = as_matrix("Phi", Phi)
    n = Phi.shape[0]
    if Phi.shape != (n, n):
        raise ShapeError(f"Phi: expected a square matrix, got shape {Phi.shape}")
    L = as_matrix("L", L, n, None)
    Qc = check_covariance("Qc", Qc, L.shape[1])
    dt = check_positive("dt", dt, allow_zero=True)
    return van_loan_unchecked(Phi, L @ Qc @ L.T, dt)


@finite_result("the discretisation e^(Phi dt), Q")
def discretize_intervals(model: ContinuousLinearModel, dts) -> tuple[np.ndarray, np.ndarray]:
    """F and Q of a continuous model over each of many intervals, exactly (Van Loan).

    For the integrator chains of the CV/CA models Van Loan's block matrix is nilpotent, so e^{M dt} is its
    finite power series, evaluated for all intervals at once; other models take one :func:`van_loan`
    exponential per distinct interval.

    Parameters
    ----------
    model : ContinuousLinearModel
        The continuous model.
    dts : array_like, shape (T,)
        The intervals (s), each >= 0.

    Returns
    -------
    F, Q : ndarray, shape (T, n, n)
        Transition matrix and process-noise covariance of each interval.

    Raises
    ------
    NonFiniteError
        An interval too long for float64 (the error names ``dts``).

    References
    ----------
    .. [1] C. F. Van Loan, "Computing integrals involving the matrix exponential", IEEE Transactions on
           Automatic Control, vol. 23, no. 3, pp. 395–404, 1978. doi:10.1109/TAC.1978.1101743
    """
    require_model(model, kind=ContinuousLinearModel)
    dts = as_vector("dts", dts, low=0.0)
    check_allocation("dts", f"{dts.shape[0]} intervals", 8.0 * dts.shape[0] * (6 * model.n) ** 2)
    with renamed(dt="dts"):
        return intervals_unchecked(model, dts)


def discretize(model: ContinuousLinearModel, dt: float) -> LinearGaussianModel:
    """The exact discrete-time model of a continuous model sampled every ``dt`` seconds.

    F = e^{Phi dt} and Q = int_0^dt e^{Phi s} L Qc L^T e^{Phi^T s} ds (Assimakis et al. 2016, sec. 2.1-2.2,
    computed by :func:`van_loan`); H and R are kept.

    Parameters
    ----------
    model : ContinuousLinearModel
        The continuous model.
    dt : float
        Sampling interval (s), > 0.

    Returns
    -------
    LinearGaussianModel

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    .. [2] C. F. Van Loan, "Computing integrals involving the matrix exponential", IEEE Transactions on
           Automatic Control, vol. 23, no. 3, pp. 395–404, 1978. doi:10.1109/TAC.1978.1101743
    """
    require_model(model, kind=ContinuousLinearModel)
    dt = check_positive("dt", dt)
    F, Q = van_loan_unchecked(model.Phi, model.L @ model.Qc @ model.L.T, dt)
    return LinearGaussianModel(F, model.H, Q, model.R, dt=dt, name=model.name)


def _axes(axes) -> int:
    axes = check_int("axes", axes, minimum=1)
    if axes > 3:
        raise ParameterError(f"axes: expected 1, 2 or 3 spatial axes, got {axes}")
    return axes


def _integrator_chain(order: int, q: float, sigma_r2: float, axes: int, name: str) -> ContinuousLinearModel:
    """``axes`` independent chains of ``order`` integrators driven at the last state, position measured."""
    Phi1 = np.eye(order, k=1)
    L1 = np.zeros((order, 1))
    L1[-1, 0] = 1.0
    H1 = np.zeros((1, order))
    H1[0, 0] = 1.0
    blocks = lambda M: scipy.linalg.block_diag(*([M] * axes))
    return ContinuousLinearModel(blocks(Phi1), blocks(L1), q * np.eye(axes), blocks(H1),
                                 sigma_r2 * np.eye(axes), name=name)


def constant_velocity_continuous(q: float, axes: int = 1, *, sigma_r2: float = 1.0) -> ContinuousLinearModel:
    """Continuous constant-velocity (white-noise acceleration) model (Assimakis et al. 2016, sec. 2.1).

    Per axis, state [s, v] (m, m/s): Phi = [[0, 1], [0, 0]], L = [0, 1]^T, position measured.

    Parameters
    ----------
    q : float
        Spectral density of the white acceleration noise (m^2/s^3), >= 0.
    axes : int, optional
        Number of independent axes (1, 2 or 3), stacked block-diagonally.
    sigma_r2 : float, optional
        Variance of the position measurement (m^2), > 0.

    Returns
    -------
    ContinuousLinearModel

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    """
    q = check_positive("q", q, allow_zero=True)
    sigma_r2 = check_positive("sigma_r2", sigma_r2)
    axes = _axes(axes)
    return _integrator_chain(2, q, sigma_r2, axes, f"CV continuous white noise ({axes} axes)")


def constant_acceleration_continuous(q: float, axes: int = 1, *,
                                     sigma_r2: float = 1.0) -> ContinuousLinearModel:
    """Continuous constant-acceleration (white-noise jerk) model (Assimakis et al. 2016, sec. 2.2).

    Per axis, state [s, v, a] (m, m/s, m/s^2): Phi = [[0, 1, 0], [0, 0, 1], [0, 0, 0]], L = [0, 0, 1]^T,
    position measured.

    Parameters
    ----------
    q : float
        Spectral density of the white jerk noise (m^2/s^5), >= 0.
    axes : int, optional
        Number of independent axes (1, 2 or 3), stacked block-diagonally.
    sigma_r2 : float, optional
        Variance of the position measurement (m^2), > 0.

    Returns
    -------
    ContinuousLinearModel

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    """
    q = check_positive("q", q, allow_zero=True)
    sigma_r2 = check_positive("sigma_r2", sigma_r2)
    axes = _axes(axes)
    return _integrator_chain(3, q, sigma_r2, axes, f"CA continuous white noise ({axes} axes)")


def constant_velocity(dt: float, q: float, axes: int = 1, *, sigma_r2: float = 1.0) -> LinearGaussianModel:
    """Exactly discretised constant-velocity model (Assimakis et al. 2016, eq. 5).

    Per axis F = [[1, dt], [0, 1]], Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]], H = [1, 0], R = sigma_r2, computed
    from :func:`constant_velocity_continuous` by Van Loan's method (not typed in).  For Q = q G G^T with
    G = [dt^2/2, dt]^T use :func:`cv_discrete_white_noise`.

    Parameters
    ----------
    dt : float
        Sampling interval (s), > 0.
    q : float
        Spectral density of the white acceleration noise (m^2/s^3), >= 0.
    axes : int, optional
        Number of independent axes (1, 2 or 3), stacked block-diagonally.
    sigma_r2 : float, optional
        Variance of the position measurement (m^2), > 0.

    Returns
    -------
    LinearGaussianModel
        The discrete-time model, states ordered axis by axis.

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    .. [2] C. F. Van Loan, "Computing integrals involving the matrix exponential", IEEE Transactions on
           Automatic Control, vol. 23, no. 3, pp. 395–404, 1978. doi:10.1109/TAC.1978.1101743

    Examples
    --------
    >>> from mptrack.models import constant_velocity
    >>> constant_velocity(1.0, 0.5, axes=2, sigma_r2=25.0).F
    array([[1., 1., 0., 0.],
           [0., 1., 0., 0.],
           [0., 0., 1., 1.],
           [0., 0., 0., 1.]])
    """
    return discretize(constant_velocity_continuous(q, axes, sigma_r2=sigma_r2), dt)


def constant_acceleration(dt: float, q: float, axes: int = 1, *, sigma_r2: float = 1.0) -> LinearGaussianModel:
    """Exactly discretised constant-acceleration model (Assimakis et al. 2016, eq. 6, its (1, 3) entry
    corrected to dt^3/6: docs/errata.md).

    Per axis F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]],
    Q = q [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]], H = [1, 0, 0],
    R = sigma_r2.  For Q = q G G^T with G = [dt^2/2, dt, 1]^T use :func:`ca_discrete_white_noise`.

    Parameters
    ----------
    dt : float
        Sampling interval (s), > 0.
    q : float
        Spectral density of the white jerk noise (m^2/s^5), >= 0.
    axes : int, optional
        Number of independent axes (1, 2 or 3), stacked block-diagonally.
    sigma_r2 : float, optional
        Variance of the position measurement (m^2), > 0.

    Returns
    -------
    LinearGaussianModel
        The discrete-time model, states ordered axis by axis.

    References
    ----------
    .. [1] N. Assimakis, G. Tziallas, M. Adam, A. Polyzos and C. Papanastasiou, "Mobile position estimation and
           prediction using steady state Kalman filter", International Journal of Computer Science and
           Information Technology Research, vol. 4, no. 3, pp. 261–272, 2016.
    .. [2] C. F. Van Loan, "Computing integrals involving the matrix exponential", IEEE Transactions on
           Automatic Control, vol. 23, no. 3, pp. 395–404, 1978. doi:10.1109/TAC.1978.1101743
    """
    return discretize(constant_acceleration_continuous(q, axes, sigma_r2=sigma_r2), dt)


def _discrete_white_noise(F1, G1, q, sigma_r2, axes, name) -> LinearGaussianModel:
    H1 = np.zeros((1, F1.shape[0]))
    H1[0, 0] = 1.0
    with derived_from(dt=F1[0, 1], q=q, sigma_r2=sigma_r2):     # G = [dt^2/2, dt(, 1)] overflows with dt
        axis = LinearGaussianModel.from_noise_gain(F1, H1, G1, [[q]], [[sigma_r2]], dt=F1[0, 1], name=name)
    return axis if axes == 1 else stack_axes(axis, axes, name=f"{name} ({axes} axes)")


def cv_discrete_white_noise(dt: float, q: float, axes: int = 1, *, sigma_r2: float = 1.0) -> LinearGaussianModel:
    """Constant velocity with discrete white-noise acceleration (Bar-Shalom et al. 2001, sec. 6.3.2).

    The acceleration is constant over each sample: per axis F = [[1, dt], [0, 1]], G = [dt^2/2, dt]^T,
    Q = q G G^T (rank 1), H = [1, 0], R = sigma_r2.  At dt = 1 this is the Q of Assimakis & Adam 2014 and
    2015, who print G = [dt/2, 1]^T (:func:`assimakis_model_b` keeps their form).

    Parameters
    ----------
    dt : float
        Sampling interval (s), > 0.
    q : float
        Variance of the acceleration (m^2/s^4), >= 0.
    axes : int, optional
        Number of independent axes (1, 2 or 3), stacked block-diagonally.
    sigma_r2 : float, optional
        Variance of the position measurement (m^2), > 0.

    Returns
    -------
    LinearGaussianModel
        The discrete-time model, states ordered axis by axis.

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    .. [2] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    dt = check_positive("dt", dt)
    q = check_positive("q", q, allow_zero=True)
    sigma_r2 = check_positive("sigma_r2", sigma_r2)
    axes = _axes(axes)
    F1 = np.array([[1.0, dt], [0.0, 1.0]])
    G1 = np.array([[0.5 * dt * dt], [dt]])
    return _discrete_white_noise(F1, G1, q, sigma_r2, axes, "CV discrete white noise")


def ca_discrete_white_noise(dt: float, q: float, axes: int = 1, *, sigma_r2: float = 1.0) -> LinearGaussianModel:
    """Constant acceleration with discrete white-noise acceleration increments (Bar-Shalom et al. 2001,
    sec. 6.3.3, the "Wiener-process acceleration").

    Per axis F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]], G = [dt^2/2, dt, 1]^T, Q = q G G^T,
    H = [1, 0, 0], R = sigma_r2.

    Parameters
    ----------
    dt : float
        Sampling interval (s), > 0.
    q : float
        Variance of the acceleration increment per sample (m^2/s^4), >= 0.
    axes : int, optional
        Number of independent axes (1, 2 or 3), stacked block-diagonally.
    sigma_r2 : float, optional
        Variance of the position measurement (m^2), > 0.

    Returns
    -------
    LinearGaussianModel
        The discrete-time model, states ordered axis by axis.

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    """
    dt = check_positive("dt", dt)
    q = check_positive("q", q, allow_zero=True)
    sigma_r2 = check_positive("sigma_r2", sigma_r2)
    axes = _axes(axes)
    F1 = np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    G1 = np.array([[0.5 * dt * dt], [dt], [1.0]])
    return _discrete_white_noise(F1, G1, q, sigma_r2, axes, "CA discrete white noise")
