"""The unscented Kalman filter (scaled unscented transform, angle-aware) and the unscented RTS smoother.

Discrete-time models (:class:`mptrack.models.NonlinearModel`): the sigma points of
N(x(k-1/k-1), P(k-1/k-1)) go through f, x(k/k-1) is their weighted mean and P(k/k-1)
their weighted covariance plus Q; the update draws new sigma points of the
prediction (as Stone Soup and Särkkä 2013 alg. 5.14 do).

Continuous-discrete models (:class:`mptrack.continuous.ContinuousDiscreteModel`; the code is in
mptrack/continuous/_ukf.py, registered with mptrack._core.model_families when mptrack.continuous is imported):

Prediction integrates the moment equations of the SDE with unscented
expectations (Särkkä 2007, IEEE TAC 52(10)):

    dm/dt = E[f(x)],   dP/dt = E[f(x)(x - m)^T] + E[(x - m) f(x)^T] + Q,

with classical RK4 sub-steps.  For a linear drift this is exactly the
Kalman prediction, so UKF ≡ KF on a linear model (a test pins it).  The
update uses the scaled unscented transform (Julier 2002; Wan & van der Merwe
2000); bearings are averaged on the circle and innovations are wrapped.

Sub-steps follow the drift: at each step the rate rho of the drift (the
largest row sum of |df/dx| at the sigma points of the prior, by forward
differences) sets h <= 0.25 / rho.  RK4's local error then stays near
(h rho)^5 / 120 ~ 1e-5 of the state's change per sub-step: on eq. 42 (Van der
Pol, Zhao, Chen & Ma 2013) that is 4-13 sub-steps per second where a fixed 20
were used, and the estimates move by ~1e-5, against a filter error of 0.36.
A model with compiled kernels (``zhao2013_model``, ``linear_sde_model``, or
``kernels=BlockKernels(...)``) runs the whole filter compiled
(``cd_ukf_run`` in mptrack/continuous/_kernels.py), with the NumPy path's
arithmetic (pinned to 1e-10 by a test) and about a hundred times faster.
"""

from __future__ import annotations

import numpy as np

from .._core.filter_inputs import check_prior, prepare_nonlinear
from .._core.finiteness import finite_result
from .._core.model_families import model_family
from .._core.unscented import check_unscented, covariance_sqrt, sigma_points, weights
from ..errors import ParameterError
from ..result import FilterResult, innovation_arrays
from ..models import NonlinearModel
from . import _named_kernels
from . import _step_kernels as steps
from ._extended import _run, check_step, named_arguments, named_result, smooth_with, user_array

__all__ = ["ukf_filter", "ukf_smoother", "sigma_points"]

def _points(x, P, c: float, X=None) -> np.ndarray:
    """The sigma points of N(x, P) with scale c = n + λ (no validation: the filters' inner loop), into X
    when given: the compiled Cholesky factor, or the eigenvalue square root of a semi-definite P."""
    X = np.empty((2 * x.shape[0] + 1, x.shape[0])) if X is None else X
    if steps.sigma_into(x, P, c, X):
        return X
    S = covariance_sqrt(c * P, "P")
    return np.concatenate([x[None], x + S.T, x - S.T])


def _unscented_predict(model: NonlinearModel, x, P, k: int, sp: tuple, x_out, P_out) -> None:
    """x(k/k-1), P(k/k-1) into x_out, P_out by the unscented transform of N(x, P) through f, plus Q(x, k);
    sp = (c, Wm, Wc, X) with X a (2n+1, n) work array for the sigma points."""
    c, Wm, Wc, X = sp
    n = model.n
    Y = user_array(model.f(_points(x, P, c, X)), (2 * n + 1, n), "f", k)
    steps.unscented_moments_into(Y, Wm, Wc, model.Q_at(x, k), x_out, P_out)


def _unscented_cross(model: NonlinearModel, x, P, sp: tuple) -> np.ndarray:
    """The cross-covariance of x(k) ~ N(x, P) and f(x(k)) by the unscented transform (the URTS's D(k))."""
    c, Wm, Wc = sp
    X = _points(x, P, c)
    Y = model.f(X)
    return (Wc[:, None] * (X - x)).T @ (Y - Wm @ Y)


def _unscented_update(model: NonlinearModel, x, P, z, k: int, sp: tuple, method: str, inputs: dict,
                      x_out, P_out, innovations: tuple) -> float:
    """The unscented update with row k of z and the sigma points of N(x(k/k-1), P(k/k-1)) through h,
    into x_out, P_out, and its innovation, S and NIS into row k of ``innovations`` (T, m), (T, m, m), (T,)."""
    c, Wm, Wc, X = sp
    X = _points(x, P, c, X)
    Z = user_array(model.h(X), (X.shape[0], model.m), "h", k)
    R = model.R_at(x, k)
    status, ll = steps.ukf_update_into(x, P, X, Z, Wm, Wc, R, z, k, model.period_array, x_out, P_out,
                                       *innovations, k)
    if status != steps.OK:
        check_step(status, method, k, x, P, {"h": Z, "R": R}, inputs)
    return ll


@finite_result("the UKF")
def ukf_filter(model, z, x0, P0, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
               substeps: int | None = None, prior: str = "initial", compiled: bool | None = None) -> FilterResult:
    """Unscented Kalman filter for a discrete-time NonlinearModel or a continuous-discrete model.

    NaN measurement components are skipped; a NaN row only predicts.  A
    :func:`~mptrack.models.nonlinear_model` of a linear motion and named measurement models runs compiled
    with the same numbers.

    Parameters
    ----------
    model : NonlinearModel or ContinuousDiscreteModel
        The model (the filter dispatches on its type).
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped, a NaN row only predicts.
    x0 : array_like, shape (n,)
        The prior mean, required.
    P0 : array_like, shape (n, n)
        The prior covariance, required.
    alpha, beta, kappa : float, optional
        Scaled unscented transform parameters (alpha > 0, beta >= 0, n + kappa > 0); the defaults keep every
        weight non-negative.  FilterPy's MerweScaledSigmaPoints and Stone Soup's UnscentedKalmanPredictor
        use the same points.
    substeps : int, optional
        Continuous-discrete models: RK4 sub-steps of the moment equations per dt (default: by the drift's
        rate at each step).
    prior : {"initial", "first-measurement"}, optional
        x0, P0 at time 0 (predicted to the first measurement), or the prior at the first measurement.
        (NonlinearModel only for "first-measurement").
    compiled : bool, optional
        Continuous-discrete models with compiled kernels: None or True run compiled, False the NumPy path
        (same numbers).

    Returns
    -------
    FilterResult

    Raises
    ------
    ConvergenceError
        The moment equations blow up (stiff drift, far from the sigma points).
    NotPositiveDefiniteError
        P loses positive semi-definiteness.

    References
    ----------
    .. [1] S. J. Julier, "The scaled unscented transformation", Proceedings of the 2002 American Control
           Conference, vol. 6, pp. 4555–4559, 2002. doi:10.1109/ACC.2002.1025369
    .. [2] E. A. Wan and R. van der Merwe, "The unscented Kalman filter for nonlinear estimation", Proceedings
           of the IEEE 2000 Adaptive Systems for Signal Processing, Communications, and Control Symposium, pp.
           153–158, 2000. doi:10.1109/ASSPCC.2000.882463
    .. [3] S. Särkkä, "On unscented Kalman filtering for state estimation of continuous-time nonlinear systems",
           IEEE Transactions on Automatic Control, vol. 52, no. 9, pp. 1631–1641, 2007.
           doi:10.1109/TAC.2007.904453
    """
    adaptive = substeps is None
    z, x, P, substeps = prepare_nonlinear(model, z, x0, P0, substeps)
    substeps = None if adaptive else substeps
    ut = check_unscented(model.n, alpha, beta, kappa)
    if isinstance(model, NonlinearModel):
        first = check_prior(prior)
        sp = weights(model.n, **ut)
        if model.named is not None:
            innovations = innovation_arrays((z.shape[0],), model.m)
            out = _named_kernels.ukf_named(*named_arguments(model), z, x, P, first, *sp, *innovations)
            if out[0] == _named_kernels.OK:
                return named_result(out, x, P, first, "UKF", innovations, inputs=ut)
        work = sp + (np.empty((2 * model.n + 1, model.n)),)

        def predict(mdl, x, P, k, x_out, P_out):
            _unscented_predict(mdl, x, P, k, work, x_out, P_out)

        def update(mdl, x, P, z, k, method, given, x_out, P_out, innovations):
            return _unscented_update(mdl, x, P, z, k, work, method, given, x_out, P_out, innovations)
        return _run(model, z, x, P, prior, predict, update, "UKF", inputs=ut)
    return model_family(model).ukf(model, z, x, P, substeps=substeps, ut=ut, prior=prior, compiled=compiled)


@finite_result("the unscented RTS smoother")
def ukf_smoother(model: NonlinearModel, result: FilterResult, *, alpha: float | None = None,
                 beta: float | None = None, kappa: float | None = None) -> FilterResult:
    """Unscented RTS smoother (Särkkä 2008) on :func:`ukf_filter`'s result for a NonlinearModel.

    C(k) = D(k) P(k+1/k)^-1 with D the unscented cross-covariance of x(k) and x(k+1).

    Parameters
    ----------
    model : NonlinearModel
        The model (f, h, Q, R and their Jacobians).
    result : FilterResult
        The UKF's result; its sigma-point parameters are read from ``result.inputs``.
    alpha, beta, kappa : float, optional
        May be omitted; values other than the filter's raise ParameterError (D must pair with the
        filter's P(k+1/k)).  For a result that does not record them: 1, 2, 0.

    Returns
    -------
    FilterResult
        x(k/T), P(k/T), and x(0/T), P(0/T) as x0, P0 (method "URTS").

    References
    ----------
    .. [1] S. Särkkä, "Unscented Rauch–Tung–Striebel smoother", IEEE Transactions on Automatic Control, vol. 53,
           no. 3, pp. 845–849, 2008. doi:10.1109/TAC.2008.919531
    """
    if not isinstance(model, NonlinearModel):
        raise ParameterError(f"model: expected a NonlinearModel, got {type(model).__name__}")
    given = {"alpha": alpha, "beta": beta, "kappa": kappa}
    recorded = result.inputs if isinstance(result, FilterResult) and result.inputs else {}
    ut = {"alpha": 1.0, "beta": 2.0, "kappa": 0.0}
    for name, value in given.items():
        if name in recorded:
            ut[name] = recorded[name]
            if value is not None and value != recorded[name]:
                raise ParameterError(f"{name}: the filter ran with {name} = {recorded[name]!r}, got {value!r}; "
                                     f"the smoother needs the filter's sigma points (omit {name})")
        elif value is not None:
            ut[name] = value
    sp = weights(model.n, **check_unscented(model.n, **ut))
    return smooth_with(model, result, lambda mdl, x, P: _unscented_cross(mdl, x, P, sp), "URTS")
