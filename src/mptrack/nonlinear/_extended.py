"""The extended Kalman filter and the extended RTS smoother on any :class:`mptrack.models.NonlinearModel`.

    x(k/k-1) = f(x(k-1/k-1)),        P(k/k-1) = F P(k-1/k-1) F^T + Q,    F = ∂f/∂x at x(k-1/k-1)
    S = H P(k/k-1) H^T + R,  K = P(k/k-1) H^T S^-1,                     H = ∂h/∂x at x(k/k-1)
    x(k/k) = x(k/k-1) + K ν,  ν = z(k) - h(x(k/k-1)) (angles wrapped)
    P(k/k) = (I - K H) P(k/k-1) (I - K H)^T + K R K^T                  (Joseph form)

The smoother is the RTS backward pass with the linearisation of the forward pass,
C(k) = P(k/k) F(k)^T P(k+1/k)^-1 (Särkkä 2013, sec. 9.1).

Per step the model (f, h, Jacobians, Q, R) is evaluated in Python and the matrix arithmetic runs in
the compiled kernels of :mod:`mptrack.nonlinear._step_kernels`; a named model runs the whole loop
compiled (:mod:`mptrack.nonlinear._named_kernels`, the same cores).
"""

from __future__ import annotations

import numpy as np

from .._core.filter_inputs import check_prior, prepare_nonlinear
from .._core.finiteness import finite_result, require_finite
from .._core.rts import rts_backward
from .._core.validation import as_array, as_vector, check_covariance, check_int, check_record
from ..errors import (
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ShapeError,
)
from ..models import NonlinearModel, require_model
from . import _named_kernels
from . import _step_kernels as steps
from ..result import BatchFilterResult, FilterResult, innovation_arrays

__all__ = ["ekf_filter", "ekf_filter_batch", "ekf_smoother", "ekf_step"]

def user_array(value, shape: tuple, name: str, k: int) -> np.ndarray:
    """A user function's value (f, h, a Jacobian) as a fresh float array of the expected shape, as the
    compiled step kernels take it (Q_at, R_at return validated read-only arrays)."""
    arr = np.array(value, dtype=float)
    if arr.shape != shape:
        raise ShapeError(f"model: its {name} gives shape {arr.shape} at measurement {k}, expected {shape}")
    return arr


def check_step(status: int, method: str, k: int, x, P, outputs: dict, inputs: dict) -> None:
    """Raise the error of a step kernel's status: NOT_PD -> NotPositiveDefiniteError; DIVERGED -> a
    NonFiniteError naming the model function that returned a non-finite value at a finite state, else
    (an overflow) the run's input of largest magnitude."""
    if status == steps.NOT_PD:
        raise NotPositiveDefiniteError(f"{method}: the innovation covariance at measurement {k} is not positive "
                                       "definite; check R and P0")
    if status == steps.DIVERGED:
        if np.isfinite(x).all() and np.isfinite(P).all():
            for name, value in outputs.items():
                if not np.isfinite(value).all():
                    raise NonFiniteError(f"model: its {name} is not finite at measurement {k} "
                                         f"(state {np.array2string(np.asarray(x), precision=6)})")
        require_finite(f"the {method} (at measurement {k})", np.nan, **inputs)


#: the ``innovations`` argument of an update whose innovation is not recorded
NOT_RECORDED = (np.empty((0, 0)), np.empty((0, 0, 0)), np.empty(0))


def ekf_update(model: NonlinearModel, x, P, z, k: int, method: str, inputs: dict, x_out, P_out,
               innovations: tuple = NOT_RECORDED, row: int | None = None) -> float:
    """EKF measurement update of x(k/k-1), P(k/k-1) with z[row] (z (T, m), row default k; NaN components
    skipped) into x_out, P_out; R(x, k); its innovation, S and NIS into row ``row`` of ``innovations``
    (the result's (T, m), (T, m, m), (T,) arrays).  Returns the log-likelihood increment.  Errors name ``method``
    and, for an overflow, the largest of ``inputs``."""
    m, n = model.m, model.n
    H = user_array(model.H_at(x), (m, n), "jac_h", k)
    hx = user_array(model.h(x[None])[0], (m,), "h", k)
    R = model.R_at(x, k)                                          # validated, read-only
    row = k if row is None else row
    status, ll = steps.ekf_update_into(x, P, H, hx, R, z, row, model.period_array, x_out, P_out, *innovations,
                                       row if innovations[0].size else -1)
    if status != steps.OK:
        check_step(status, method, k, x, P, {"jac_h": H, "h": hx, "R": R}, inputs)
    return ll


def ekf_predict(model: NonlinearModel, x, P, k: int, x_out, P_out) -> None:
    """x(k/k-1) = f(x), P(k/k-1) = F P F^T + Q(x, k) from x(k-1/k-1), P(k-1/k-1) into x_out, P_out."""
    n = model.n
    F = user_array(model.F_at(x), (n, n), "jac_f", k)
    steps.ekf_predict_into(F, P, model.Q_at(x, k), P_out)
    x_out[:] = user_array(model.f(x[None])[0], (n,), "f", k)


@finite_result("the EKF step")
def ekf_step(model: NonlinearModel, x, P, z, k: int = 0):
    """One EKF iteration from x(k-1/k-1), P(k-1/k-1) with one measurement.

    Parameters
    ----------
    model : NonlinearModel
        The model (f, h, Q, R and their Jacobians).
    x : array_like, shape (n,)
        x(k-1/k-1).
    P : array_like, shape (n, n)
        P(k-1/k-1).
    z : array_like, shape (m,)
        The measurement (NaN components skipped).
    k : int, optional
        The measurement's index (for Q(x, k), R(x, k)).

    Returns
    -------
    x_filt, P_filt, x_pred, P_pred : ndarray
    loglik : float
        The log-likelihood increment.

    References
    ----------
    .. [1] S. Särkkä, Bayesian Filtering and Smoothing, Cambridge University Press, 2013.
           doi:10.1017/CBO9781139344203
    """
    model = require_model(model, kind=NonlinearModel)
    x = np.array(as_vector("x", x, model.n))
    P = np.array(check_covariance("P", P, model.n))
    z = np.array(as_array("z", z, shape=(model.m,), allow_nan=True))
    k = check_int("k", k, minimum=0)
    xp, Pp, xu, Pu = np.empty_like(x), np.empty_like(P), np.empty_like(x), np.empty_like(P)
    ekf_predict(model, x, P, k, xp, Pp)
    ll = ekf_update(model, xp, Pp, z[None], k, "EKF", {"x": x, "P": P, "z": z}, xu, Pu, row=0)
    return xu, Pu, xp, Pp, ll


def _run(model, z, x0, P0, prior, predict, update, method, inputs=None):
    """The driver loop shared by the EKF and the discrete UKF, writing into the result's rows:
    predict(model, x, P, k, x_out, P_out) and update(model, x, P, z, k, method, given, x_out, P_out,
    innovations) -> loglik (with row k of z, its innovation, S and NIS into row k of the result's
    arrays ``innovations``); ``inputs`` (the filter's settings for its smoother) go into the result."""
    first = check_prior(prior)
    T, n = z.shape[0], model.n
    observed = ~np.isnan(z).all(axis=1)
    given = {"z": z, "x0": x0, "P0": P0}
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    xp, Pp = np.empty((T, n)), np.empty((T, n, n))
    nu, S, nis = innovation_arrays((T,), model.m)
    x, P, loglik = np.array(x0), np.array(P0), 0.0
    for k in range(T):
        if first and k == 0:
            xp[0], Pp[0] = x, P
        else:
            predict(model, x, P, k, xp[k], Pp[k])
        if observed[k]:
            loglik += update(model, xp[k], Pp[k], z, k, method, given, xs[k], Ps[k], (nu, S, nis))
        else:
            xs[k], Ps[k] = xp[k], Pp[k]
        x, P = xs[k], Ps[k]
    # a non-finite estimate from finite input is an overflow: name the largest input
    require_finite(f"the {method}", (xs, Ps), **given)
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method=method,
                        x0=None if first else x0, P0=None if first else P0, inputs=inputs, innovation=nu, S=S,
                        nis=nis)


@finite_result("the EKF")
def ekf_filter(model: NonlinearModel, z, x0, P0, *, prior: str = "initial") -> FilterResult:
    """Extended Kalman filter.

    Q(x, k) is evaluated at x(k-1/k-1) and R(x, k) at x(k/k-1).  A
    :func:`~mptrack.models.nonlinear_model` of a linear motion and named measurement models (ranges,
    bearings, range_bearing, position, stacks of them; constant R) runs compiled with the same numbers.

    Parameters
    ----------
    model : NonlinearModel
        The model (f, h, Q, R and their Jacobians).
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped, a NaN row only predicts.
    x0 : array_like, shape (n,)
        The prior mean, required.
    P0 : array_like, shape (n, n)
        The prior covariance, required.
    prior : {"initial", "first-measurement"}, optional
        x0, P0 at time 0 (predicted to the first measurement), or the prior at the first measurement.

    Returns
    -------
    FilterResult
        With x0, P0 the prior at time 0 (for :func:`ekf_smoother`).

    Raises
    ------
    NotPositiveDefiniteError
        An innovation covariance is not positive definite.
    NonFiniteError
        A model function returned a non-finite value, or the filter overflowed.

    References
    ----------
    .. [1] S. Särkkä, Bayesian Filtering and Smoothing, Cambridge University Press, 2013.
           doi:10.1017/CBO9781139344203

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack.models import constant_velocity, nonlinear_model, range_bearing
    >>> from mptrack.nonlinear import ekf_filter
    >>> model = nonlinear_model(constant_velocity(1.0, 0.5, axes=2), range_bearing([0.0, 0.0], [1e-4, 4.0]))
    >>> z = np.array([[0.1, 100.0], [0.11, 101.0], [np.nan, 102.0]])
    >>> result = ekf_filter(model, z, x0=[99.0, 1.0, 10.0, 0.0], P0=np.eye(4) * 25.0)
    >>> result.x.shape
    (3, 4)
    """
    z, x0, P0, _ = prepare_nonlinear(model, z, x0, P0, kinds=(NonlinearModel,))
    if model.named is not None:
        first = check_prior(prior)
        innovations = innovation_arrays((z.shape[0],), model.m)
        out = _named_kernels.ekf_named(*named_arguments(model), z, x0, P0, first, *innovations)
        if out[0] == _named_kernels.OK:
            return named_result(out, x0, P0, first, "EKF", innovations)
    return _run(model, z, x0, P0, prior, ekf_predict, ekf_update, "EKF")


def named_arguments(model: NonlinearModel) -> tuple:
    """(F, Q, R, codes, pos, stations, periods) of a model tagged by nonlinear_model for the compiled kernels."""
    F, codes, pos, stations = model.named
    return F, model.Q, model.R, codes, pos, stations, model.period_array


def named_result(out, x0, P0, first: bool, method: str, innovations: tuple, inputs=None) -> FilterResult:
    """The FilterResult of a compiled run (status, step, xs, Ps, xp, Pp, loglik) that succeeded, with the
    innovations, their covariances and NIS it wrote."""
    _, _, xs, Ps, xp, Pp, loglik = out
    nu, S, nis = innovations
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method=method,
                        x0=None if first else x0, P0=None if first else P0, inputs=inputs, innovation=nu, S=S,
                        nis=nis)


def _check_result(model, result) -> None:
    if not isinstance(model, NonlinearModel):
        raise ParameterError(f"model: expected a NonlinearModel, got {type(model).__name__}")
    if not isinstance(result, FilterResult) or result.x_pred is None:
        raise ParameterError(f"result: expected the FilterResult of a filter run, got {type(result).__name__}")
    check_record("result", result)
    if result.n != model.n:
        raise ParameterError(f"result: state dimension {result.n} does not match the model's n = {model.n}")


def smooth_with(model, result, cross, method):
    """Backward pass given cross(model, x, P) = the cross-covariance of x(k-1) and x(k) (n, n) of the
    forward linearisation at the filtered x(k-1/k-1), P(k-1/k-1).  The predictions P(k/k-1) (with
    Q(x, k) of the filter's own step k) come from the result: the smoother never evaluates Q."""
    _check_result(model, result)
    has0 = result.x0 is not None
    xf = np.concatenate([result.x0[None], result.x]) if has0 else np.asarray(result.x)
    Pf = np.concatenate([result.P0[None], result.P]) if has0 else np.asarray(result.P)
    start = 0 if has0 else 1
    xp, Pp = result.x_pred[start:], result.P_pred[start:]
    D = np.stack([cross(model, xf[i], Pf[i]) for i in range(len(xf) - 1)])
    xs, Ps = rts_backward(xf, Pf, xp, Pp, D)
    if has0:
        return FilterResult(x=xs[1:], P=Ps[1:], method=method, x0=xs[0], P0=Ps[0])
    return FilterResult(x=xs, P=Ps, method=method)


@finite_result("the extended RTS smoother")
def ekf_smoother(model: NonlinearModel, result: FilterResult) -> FilterResult:
    """Extended RTS smoother on :func:`ekf_filter`'s result.

    Parameters
    ----------
    model : NonlinearModel
        The model (f, h, Q, R and their Jacobians).
    result : FilterResult
        The EKF's result (its predictions are reused; only the Jacobian of f is evaluated).

    Returns
    -------
    FilterResult
        x(k/T), P(k/T) (method "ERTS"), and x(0/T), P(0/T) as x0, P0 when the filter's prior was at time 0.

    References
    ----------
    .. [1] S. Särkkä, Bayesian Filtering and Smoothing, Cambridge University Press, 2013.
           doi:10.1017/CBO9781139344203
    """
    return smooth_with(model, result, lambda mdl, x, P: P @ mdl.F_at(x).T, "ERTS")


@finite_result("the EKF")
def ekf_filter_batch(model: NonlinearModel, z, x0, P0) -> BatchFilterResult:
    """:func:`ekf_filter` on B independent tracks at once (prior at time 0).

    The model's functions are called on all B states at once and the algebra runs in the compiled Kalman
    core, track by track (constant Q and R); Jacobians from jac_f / jac_h on all states at once, or by
    finite differences.  A linear motion with named measurement models runs whole compiled (same numbers).

    Parameters
    ----------
    model : NonlinearModel
        The model (f, h, Q, R and their Jacobians).
    z : array_like, shape (B, T, m)
        Measurements; NaN = missing.
    x0 : array_like, shape (n,) or (B, n)
        The prior mean(s).
    P0 : array_like, shape (n, n) or (B, n, n)
        The prior covariance(s).

    Returns
    -------
    BatchFilterResult
        x, P, x_pred, P_pred, innovation, S, nis and loglik (B,).

    Raises
    ------
    ParameterError
        A callable Q or R (use :func:`ekf_filter` per track).
    SingularMatrixError
        An innovation covariance became singular (the message names the input of smallest scale).

    References
    ----------
    .. [1] S. Särkkä, Bayesian Filtering and Smoothing, Cambridge University Press, 2013.
           doi:10.1017/CBO9781139344203
    """
    if not isinstance(model, NonlinearModel):
        raise ParameterError(f"model: expected a NonlinearModel, got {type(model).__name__}")
    if callable(model.Q) or callable(model.R):
        raise ParameterError("model: the batch EKF needs constant Q and R (use ekf_filter per track for Q(x, k), "
                             "R(x, k))")
    z = as_array("z", z, ndim=3, allow_nan=True)
    B, T, m = z.shape
    n = model.n
    if m != model.m or T == 0:
        raise ShapeError(f"z: expected shape (B, T >= 1, {model.m}), got {z.shape}")
    x0 = as_array("x0", x0)
    if x0.shape not in ((n,), (B, n)):
        raise ShapeError(f"x0: expected shape ({n},) or ({B}, {n}), got {x0.shape}")
    P0 = as_array("P0", P0)
    P0 = check_covariance("P0", P0, n) if P0.ndim != 3 else np.stack(
        [check_covariance(f"P0[{b}]", p, n) for b, p in enumerate(P0)])
    x0, P0 = np.broadcast_to(x0, (B, n)).copy(), np.broadcast_to(P0, (B, n, n)).copy()
    if model.named is not None:
        xs, xp = np.empty((B, T, n)), np.empty((B, T, n))
        Ps, Pp = np.empty((B, T, n, n)), np.empty((B, T, n, n))
        ll = np.empty(B)
        nu, S, nis = innovation_arrays((B, T), m)
        status, _, _ = _named_kernels.ekf_named_batch(*named_arguments(model), z, x0, P0, xs, Ps, xp, Pp, nu, S,
                                                      nis, ll)
        if status == _named_kernels.OK:
            return BatchFilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=ll, method="EKF", innovation=nu, S=S,
                                     nis=nis)
    xs, Ps, xp, Pp, ll, nu, S, nis = _ekf_batch_core(model, z, x0, P0)
    return BatchFilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=ll, method="EKF", innovation=nu, S=S, nis=nis)


def _jacobians(model, X, which):
    fn, rows = (model.jac_f, model.n) if which == "f" else (model.jac_h, model.m)
    if fn is not None:
        J = np.asarray(fn(X), dtype=float)
        if J.shape == (X.shape[0], rows, model.n):
            return J
        return np.stack([np.asarray(fn(x), dtype=float) for x in X])
    return np.stack([model.F_at(x) if which == "f" else model.H_at(x) for x in X])


def _ekf_batch_core(model, z, x, P):
    """The batched EKF recursion (Joseph form; NaN components skipped): the model's functions evaluated on
    all B states at once in NumPy, the algebra track by track in the compiled Kalman core
    (``_step_kernels.ekf_predict_tracks`` / ``ekf_update_tracks``).  Returns (x, P, x_pred, P_pred, loglik,
    innovation, S, nis)."""
    B, T, m = z.shape
    n = model.n
    Q, R = np.asarray(model.Q, dtype=float), np.asarray(model.R, dtype=float)
    xs, xp = np.empty((B, T, n)), np.empty((B, T, n))
    Ps, Pp = np.empty((B, T, n, n)), np.empty((B, T, n, n))
    loglik = np.zeros(B)
    nus, Ss, nis = innovation_arrays((B, T), m)
    P = np.ascontiguousarray(P, dtype=float)
    for k in range(T):
        F = np.ascontiguousarray(_jacobians(model, x, "f"), dtype=float)
        x = np.array(model.f(x), dtype=float)
        steps.ekf_predict_tracks(F, P, Q, Pp[:, k])
        xp[:, k] = x
        H = np.ascontiguousarray(_jacobians(model, x, "h"), dtype=float)
        hx = np.array(model.h(x), dtype=float)
        status, b = steps.ekf_update_tracks(x, P, H, hx, R, z, k, model.period_array, xs, Ps, nus, Ss, nis, loglik)
        if status == steps.NOT_PD:   # a singular S: the public function names the input of smallest scale
            raise np.linalg.LinAlgError(f"the innovation covariance of track {b} at measurement {k} is singular")
        if status != steps.OK:
            check_step(status, "EKF", k, xp[b, k], Pp[b, k], {"jac_h": H[b], "h": hx[b]},
                       {"z": z, "model": model.Q})
    return xs, Ps, xp, Pp, loglik, nus, Ss, nis
