"""Parameter learning for linear-Gaussian models: EM (Shumway & Stoffer 1982) and direct
maximisation of the Kalman filter's likelihood.

EM alternates an E-step -- the Kalman filter and the RTS smoother of :mod:`mptrack.linear`, giving the
smoothed means mu(s), covariances V(s) and the lag-one covariances V(s, s-1) = V(s) C(s-1)^T from the
smoother gains C -- with an M-step that maximises the expected complete-data log-likelihood in closed
form (Shumway & Stoffer 2017, sec. 6.3; Ghahramani & Hinton 1996):

    F  = (sum V(s, s-1) + mu(s) mu(s-1)^T - Bu(s) mu(s-1)^T) (sum V(s-1) + mu(s-1) mu(s-1)^T)^-1
    Q  = 1/N sum E[(x(s) - F x(s-1) - Bu(s)) (.)^T]          (Qw = G^+ Q G^+T for a model given as G, Qw)
    H  = (sum E[z x^T]) (sum E[x x^T])^-1,   R = 1/n sum E[(z - H x) (.)^T]   (rows with a measurement)
    x0 = mu(0),   P0 = V(0) + (mu(0) - x0) (mu(0) - x0)^T

over the N transitions and the n measurement rows.  A row with some components missing (NaN) enters
with the missing components' conditional distribution given the observed ones (Shumway & Stoffer
2017, sec. 6.4); a row with none is left out of H and R, as pykalman does.  Each M-step updates H
before R and F before Q, so (H, R) and (F, Q) are joint maximisers; the log-likelihood never
decreases (up to rounding).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Mapping

import numpy as np
import scipy.optimize

from .._core.blas import one_blas_thread
from .._core.finiteness import finite_result
from .._core.rts import rts_backward
from .._core.validation import as_real, check_int
from ..errors import ConvergenceError, MptrackError, NotPositiveDefiniteError, ParameterError
from ..models import LinearGaussianModel, require_model
from ._common import prepare_inputs
from ._kalman import PRIORS, kalman_filter, step_matrices

__all__ = ["FitResult", "fit_em", "fit_ml"]

#: what fit_em can estimate
EM_PARAMETERS = ("F", "H", "Q", "R", "x0", "P0")


@dataclasses.dataclass(frozen=True, eq=False)
class FitResult:
    """A fitted linear-Gaussian model (:func:`fit_em`, :func:`fit_ml`).

    model       the fitted LinearGaussianModel
    x0, P0      the prior (fitted by EM when listed in ``estimate``, else as given)
    loglik      (k+1,) log-likelihood of z under the model after 0, 1, .., k iterations: loglik[0]
                is the starting model's, loglik[-1] the fitted model's
    iterations  k, the iterations run
    converged   True when the tolerance stopped the iterations (False: the iteration limit did)
    method      "EM" or "ML"
    params      (fit_ml) the fitted parameters {name: value}
    stderr      (fit_ml) their standard errors from the observed information (the inverse Hessian of
                the log-likelihood)
    cov         (fit_ml) the covariance matrix of the parameters, in the order of ``params``
    """

    model: LinearGaussianModel
    x0: np.ndarray
    P0: np.ndarray
    loglik: np.ndarray
    iterations: int
    converged: bool
    method: str
    params: dict | None = None
    stderr: dict | None = None
    cov: np.ndarray | None = None


# ================================================================ EM

@finite_result("the EM fit")
def fit_em(model: LinearGaussianModel, z, *, x0=None, P0, estimate=("Q", "R", "x0", "P0"),
           iterations: int = 100, tol: float = 1e-8, prior: str = "initial", B=None, u=None) -> FitResult:
    """Fit the matrices of a linear-Gaussian model to measurements by expectation-maximisation.

    Parameters
    ----------
    model : LinearGaussianModel
        The starting model; the matrices not listed in ``estimate`` stay fixed.  A model given as a
        noise gain G with Qw (``LinearGaussianModel.from_noise_gain``) keeps G: "Q" then fits Qw.
    z : array_like, shape (T, m)
        Measurements; NaN components are missing.
    x0 : array_like, shape (n,), optional
        The prior mean (default zeros); fitted when "x0" is in ``estimate``.
    P0 : array_like, shape (n, n)
        The prior covariance (required); fitted when "P0" is in ``estimate``.
    estimate : iterable of str
        What to fit, any of "F", "H", "Q", "R", "x0", "P0".  One track cannot determine P0: its fit
        shrinks towards the smoothed covariance at the prior's time.
    iterations : int
        The most EM iterations to run.
    tol : float
        Stop when an iteration raises the log-likelihood by less than ``tol`` times its magnitude;
        0 runs all ``iterations``.
    prior : {"initial", "first-measurement"}
        Where (x0, P0) sits, as in :func:`kalman_filter`: at time 0, one prediction before z[0], or
        at z[0] itself (pykalman's convention).
    B, u : array_like, optional
        A known control input B u(k) added to the prediction into z[k], as in :func:`kalman_filter`
        (pykalman's transition offsets are B = I, u(k) = offset(k-1)).

    Returns
    -------
    FitResult
        The fitted model and prior, and the log-likelihood after each iteration (never decreasing,
        up to rounding).

    Raises
    ------
    ParameterError
        An unknown name in ``estimate``; "Q" of a model whose noise gain G does not have full column
        rank; z without any measurement, or with a single time while "F" or "Q" is fitted.
    NotPositiveDefiniteError
        The fitted R is singular: the model reproduces some measurement component exactly.
    ShapeError, NonFiniteError
        As :func:`kalman_filter`, for z, x0, P0, B and u.

    References
    ----------
    .. [1] R. H. Shumway and D. S. Stoffer, "An approach to time series smoothing and forecasting using the EM
           algorithm", Journal of Time Series Analysis, vol. 3, no. 4, pp. 253–264, 1982.
           doi:10.1111/j.1467-9892.1982.tb00349.x
    .. [2] Z. Ghahramani and G. E. Hinton, "Parameter estimation for linear dynamical systems", Technical
           Report CRG-TR-96-2, University of Toronto, 1996.
    .. [3] R. H. Shumway and D. S. Stoffer, Time Series Analysis and Its Applications, 4th ed., Springer,
           2017. doi:10.1007/978-3-319-52452-8

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack.linear import fit_em
    >>> from mptrack.models import constant_velocity
    >>> from mptrack.sim import simulate_linear
    >>> truth = constant_velocity(1.0, 0.5, sigma_r2=9.0)
    >>> _, z = simulate_linear(truth, 500, np.random.default_rng(1))
    >>> start = constant_velocity(1.0, 1.0, sigma_r2=1.0)
    >>> fit = fit_em(start, z, P0=np.eye(2), estimate=("Q", "R"))
    >>> bool(np.all(np.diff(fit.loglik) > -1e-9 * abs(fit.loglik[-1])))
    True
    """
    require_model(model)
    wanted = _estimate_names(estimate)
    iterations = check_int("iterations", iterations, minimum=0)
    tol = as_real("tol", tol, low=0.0)
    if prior not in PRIORS:
        raise ParameterError(f"prior: expected one of {PRIORS}, got {prior!r}")
    if "Q" in wanted and model.G is not None and np.linalg.matrix_rank(model.G) < model.G.shape[1]:
        raise ParameterError(f"model: its noise gain G ({model.G.shape[0]} x {model.G.shape[1]}) must have full "
                             "column rank for EM to fit Qw")
    z, x0, P0 = _prepare(model, z, x0, P0)
    if np.isnan(z).all():
        raise ParameterError("z: no measurement (every value is NaN): there is nothing to fit")
    fitted_transitions = wanted & {"F", "Q"}
    if fitted_transitions and z.shape[0] < (2 if prior == PRIORS[1] else 1):
        raise ParameterError(f"z: fitting {' and '.join(sorted(fitted_transitions))} needs a transition: at least two "
                             "measurement times with the prior at the first")
    converged = False
    with one_blas_thread(model.n):      # few-by-few matrices: BLAS's threads would only spin
        state = _EMState(model, z, x0, P0, prior, B, u)
        loglik = [state.loglik]
        for _ in range(iterations):
            state = state.m_step(wanted)
            loglik.append(state.loglik)
            if tol > 0 and loglik[-1] - loglik[-2] <= tol * abs(loglik[-1]):
                converged = True
                break
    return FitResult(model=state.model, x0=state.x0, P0=state.P0, loglik=np.array(loglik),
                     iterations=len(loglik) - 1, converged=converged, method="EM")


def _estimate_names(estimate) -> frozenset:
    names = (estimate,) if isinstance(estimate, str) else estimate
    try:
        names = tuple(names)
    except TypeError:
        raise ParameterError(f"estimate: expected names among {EM_PARAMETERS}, got {estimate!r}") from None
    bad = [name for name in names if not isinstance(name, str) or name not in EM_PARAMETERS]
    if bad or not names:
        raise ParameterError(f"estimate: expected one or more of {EM_PARAMETERS}, got {estimate!r}")
    return frozenset(names)


class _EMState:
    """A model with its prior and the E-step on z: the smoothed moments and the log-likelihood."""

    def __init__(self, model, z, x0, P0, prior, B, u):
        result = kalman_filter(model, z, x0, P0, B=B, u=u, prior=prior)   # validates B, u
        self.model, self.z, self.x0, self.P0, self.prior, self.B, self.u = model, z, x0, P0, prior, B, u
        self.loglik = float(result.loglik)
        T = z.shape[0]
        Bu = None if B is None else step_matrices(model, T, B=B, u=u)["Bu"]
        if prior == "initial":       # states 0..T; measurement row k belongs to state k+1
            xf = np.concatenate([x0[None], result.x])
            Pf = np.concatenate([P0[None], result.P])
            xp, Pp = result.x_pred, result.P_pred
            self.rows = np.arange(1, T + 1)
            self.Bu = Bu
        else:                        # states 0..T-1 at the measurements; no prediction into row 0
            xf, Pf = result.x, result.P
            xp, Pp = result.x_pred[1:], result.P_pred[1:]
            self.rows = np.arange(T)
            self.Bu = None if Bu is None else Bu[1:]
        self.transitions = xf.shape[0] - 1
        if self.transitions:
            self.mu, self.V, C = rts_backward(xf, Pf, xp, Pp, Pf[:-1] @ model.F.T, gains=True)
            self.V_lag = self.V[1:] @ np.swapaxes(C, 1, 2)       # Cov(x(s), x(s-1) | z), s = 1..N
        else:
            self.mu, self.V, self.V_lag = xf, Pf, Pf[:0]

    def m_step(self, wanted: frozenset) -> "_EMState":
        m = self.model
        F, H, Q, R, Qw = m.F, m.H, m.Q, m.R, m.Qw
        if "H" in wanted or "R" in wanted:
            H, R = self._measurement(wanted)
        if "F" in wanted or "Q" in wanted:
            F, Q = self._transition(wanted)
            if "Q" in wanted and m.G is not None:
                Gp = np.linalg.pinv(m.G)
                Qw = _sym(Gp @ Q @ Gp.T)
        x0, P0 = self.x0, self.P0
        if "x0" in wanted:
            x0 = self.mu[0].copy()
        if "P0" in wanted:
            d = self.mu[0] - x0
            P0 = _sym(self.V[0] + np.outer(d, d))
        meta = dict(dt=m.dt, name=m.name)
        try:
            if m.G is not None:
                new = LinearGaussianModel.from_noise_gain(F, H, m.G, Qw, R, **meta)
            else:
                new = LinearGaussianModel(F, H, Q, R, **meta)
        except NotPositiveDefiniteError as exc:
            raise NotPositiveDefiniteError(f"z: the EM estimate of a covariance is singular ({exc}); the model "
                                           "reproduces the measurements exactly in some direction") from exc
        return _EMState(new, self.z, x0, P0, self.prior, self.B, self.u)

    def _transition(self, wanted: frozenset):
        """(F, Q) of the M-step: F by least squares on the smoothed moments, Q from the residuals."""
        mu, V, V_lag = self.mu, self.V, self.V_lag
        prev, nxt = mu[:-1], mu[1:]
        bu = np.zeros_like(nxt) if self.Bu is None else self.Bu
        F = self.model.F
        if "F" in wanted:
            S00 = V[:-1].sum(axis=0) + prev.T @ prev
            S10 = V_lag.sum(axis=0) + nxt.T @ prev - bu.T @ prev
            F = np.linalg.lstsq(S00, S10.T, rcond=None)[0].T      # S00 is symmetric: F = S10 S00^-1
        if "Q" not in wanted:
            return F, self.model.Q
        r = nxt - prev @ F.T - bu
        lag = V_lag.sum(axis=0) @ F.T
        Q = (r.T @ r + F @ V[:-1].sum(axis=0) @ F.T + V[1:].sum(axis=0) - lag - lag.T) / self.transitions
        return F, _sym(Q)

    def _measurement(self, wanted: frozenset):
        """(H, R) of the M-step from the expected moments of each measurement row with its state."""
        m = self.model
        seen = ~np.isnan(self.z)
        used = seen.any(axis=1)
        mu, V = self.mu[self.rows[used]], self.V[self.rows[used]]
        z, seen = self.z[used], seen[used]
        # each row as z = a + E x + e with x ~ N(mu, V) and e ~ N(0, Se) independent of x: the observed
        # components as they are, the missing ones of a partly observed row from their law given the
        # observed ones (E and e are zero on complete rows, so only partly observed rows carry them)
        a, part, E, Se = _conditional_rows(z, seen, m.H, m.R)
        EV = E @ V[part]                                         # (rows with a missing component, m, n)
        Ez = a.copy()
        Ez[part] += np.einsum("tij,tj->ti", E, mu[part])
        H = m.H
        if "H" in wanted:
            Sxx = V.sum(axis=0) + mu.T @ mu
            Szx = Ez.T @ mu + EV.sum(axis=0)
            H = np.linalg.lstsq(Sxx, Szx.T, rcond=None)[0].T
        if "R" not in wanted:
            return H, m.R
        # sum of Cov(z - H x) = (E - H) V (E - H)^T + Se over the rows, E zero on the complete ones
        r = Ez - mu @ H.T
        EVH = EV.sum(axis=0) @ H.T
        cov = H @ V.sum(axis=0) @ H.T + np.einsum("tij,tkj->ik", EV, E) - EVH - EVH.T + Se
        return H, _sym((r.T @ r + cov) / z.shape[0])


def _conditional_rows(z, seen, H, R):
    """Measurement rows (q, m) as z = a + E x + e (module docstring): a = the observed values and, for a
    missing component u of a partly observed row, R_uo R_oo^-1 z_o; E = H_u - R_uo R_oo^-1 H_o on the
    missing components (zero elsewhere); e ~ N(0, R_uu - R_uo R_oo^-1 R_ou) there.  Returns (a (q, m),
    the indices (p,) of the partly observed rows, their E (p, m, n), the sum of their covariances of e)."""
    q, mdim = z.shape
    a = np.where(seen, z, 0.0)
    part = np.flatnonzero(~seen.all(axis=1))
    E = np.zeros((part.size, mdim, H.shape[1]))
    Se = np.zeros((mdim, mdim))
    codes = seen[part] @ (1 << np.arange(mdim))
    for code in np.unique(codes):
        at = np.flatnonzero(codes == code)
        rows = part[at]
        o = seen[rows[0]]
        u = ~o
        W = np.linalg.solve(R[np.ix_(o, o)], R[np.ix_(o, u)]).T        # R_uo R_oo^-1
        a[np.ix_(rows, u)] = z[np.ix_(rows, o)] @ W.T
        E[np.ix_(at, u)] = H[u] - W @ H[o]
        Se[np.ix_(u, u)] += rows.size * (R[np.ix_(u, u)] - W @ R[np.ix_(o, u)])
    return a, part, E, Se


def _prepare(model, z, x0, P0):
    """(z, x0, P0) validated as :func:`kalman_filter` does; P0 is required."""
    if P0 is None:
        raise ParameterError("P0: the prior covariance is required (np.zeros((n, n)) for a known x0)")
    return prepare_inputs(model, z, x0, P0)[:3]


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)


# ================================================================ direct maximisation

@finite_result("the likelihood fit")
def fit_ml(model: Callable[..., LinearGaussianModel], z, params: Mapping[str, float], *, x0=None, P0,
           positive=None, iterations: int = 200, tol: float = 1e-10, prior: str = "initial", B=None,
           u=None) -> FitResult:
    """Fit the parameters of a parameterised linear-Gaussian model by maximising the likelihood.

    The log-likelihood of z is the Kalman filter's (:func:`kalman_filter`, its ``loglik``); it is
    maximised by quasi-Newton iterations (L-BFGS) on central-difference gradients, and the standard
    errors come from the observed information, the negative Hessian of the log-likelihood at the
    maximum (central differences), by the delta method for the parameters fitted on the log scale.

    Parameters
    ----------
    model : callable
        ``model(**params)`` returns the LinearGaussianModel for parameter values, e.g.
        ``lambda q, sigma: constant_velocity(1.0, q, sigma_r2=sigma**2)``.
    z : array_like, shape (T, m)
        Measurements; NaN components are missing.
    params : mapping of str to float
        The parameters' starting values, e.g. ``{"q": 1.0, "sigma": 5.0}``.
    x0 : array_like, shape (n,), optional
        The prior mean (default zeros).
    P0 : array_like, shape (n, n)
        The prior covariance (required).
    positive : iterable of str, optional
        The parameters that must be > 0 (fitted on the log scale); default: all of them, as noise
        parameters are.  Give ``()`` for parameters of any sign.
    iterations : int
        The most quasi-Newton iterations (>= 1).
    tol : float
        Stop when an iteration raises the log-likelihood by less than ``tol`` times its magnitude.
    prior : {"initial", "first-measurement"}
        Where (x0, P0) sits, as in :func:`kalman_filter`.
    B, u : array_like, optional
        A known control input, as in :func:`kalman_filter`.

    Returns
    -------
    FitResult
        The fitted model, ``params``, ``stderr`` and ``cov``, and the log-likelihood after each
        iteration.

    Raises
    ------
    ParameterError
        ``model`` is not callable or does not return a LinearGaussianModel; ``params`` is empty, holds
        a value that is not a finite real number, or a non-positive value of a ``positive`` parameter;
        ``positive`` names a parameter that ``params`` does not have; the model cannot be built or
        filtered at the starting values; the data do not determine a parameter (the log-likelihood is
        flat along it at the maximum: a parameter the model ignores, or a variance whose estimate
        goes to 0).
    ConvergenceError
        The likelihood cannot be evaluated at a point the search reaches (the message gives it), or
        the iterations ran out before a maximum (no standard errors there).
    ShapeError, NonFiniteError
        As :func:`kalman_filter`, for z, x0, P0, B and u.

    References
    ----------
    .. [1] F. C. Schweppe, "Evaluation of likelihood functions for Gaussian signals", IEEE Transactions on
           Information Theory, vol. 11, no. 1, pp. 61–70, 1965. doi:10.1109/TIT.1965.1053737
    .. [2] R. H. Shumway and D. S. Stoffer, Time Series Analysis and Its Applications, 4th ed., Springer,
           2017. doi:10.1007/978-3-319-52452-8

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack.linear import fit_ml
    >>> from mptrack.models import constant_velocity
    >>> from mptrack.sim import simulate_linear
    >>> cv = lambda q, sigma: constant_velocity(1.0, q, sigma_r2=sigma**2)
    >>> _, z = simulate_linear(cv(0.5, 3.0), 500, np.random.default_rng(1))
    >>> fit = fit_ml(cv, z, {"q": 1.0, "sigma": 1.0}, P0=np.zeros((2, 2)))
    >>> sorted(fit.params)
    ['q', 'sigma']
    """
    if isinstance(model, LinearGaussianModel) or not callable(model):
        raise ParameterError("model: expected a function of the parameters returning a LinearGaussianModel "
                             f"(e.g. lambda q, sigma: constant_velocity(1.0, q, sigma_r2=sigma**2)), got "
                             f"{type(model).__name__}")
    names, start = _check_params(params)
    log = _positive_mask(positive, names)
    for name, value, on_log in zip(names, start, log):
        if on_log and not value > 0:
            raise ParameterError(f"params: {name} must be > 0 (it is fitted on the log scale; list the parameters "
                                 f"of any sign in positive=), got {value!r}")
    iterations = check_int("iterations", iterations, minimum=1)
    tol = as_real("tol", tol, low=0.0)
    if prior not in PRIORS:
        raise ParameterError(f"prior: expected one of {PRIORS}, got {prior!r}")

    def natural(theta):
        return dict(zip(names, np.where(log, np.exp(np.where(log, theta, 0.0)), theta).tolist()))

    def build(theta):
        values = natural(theta)
        try:
            built = model(**values)
        except (MptrackError, TypeError, ValueError, ArithmeticError) as exc:   # the caller's function failed
            raise ParameterError(f"params: model({_show(values)}) failed: {type(exc).__name__}: {exc}") from exc
        if not isinstance(built, LinearGaussianModel):
            raise ParameterError(f"model: expected a function returning a LinearGaussianModel, got "
                                 f"{type(built).__name__}")
        return built

    theta0 = np.where(log, np.log(np.where(log, start, 1.0)), start)
    # the starting point: argument errors of z, x0, P0, B, u and of the model come out here, named
    z, x0, P0 = _prepare(build(theta0), z, x0, P0)
    first = kalman_filter(build(theta0), z, x0, P0, B=B, u=u, prior=prior)

    def loglik(theta):
        try:
            with np.errstate(all="ignore"):
                value = kalman_filter(build(theta), z, x0, P0, B=B, u=u, prior=prior).loglik
        except MptrackError as exc:
            raise ConvergenceError(f"params: the likelihood cannot be evaluated at {_show(natural(theta))}, where "
                                   f"the search went from {_show(natural(theta0))}: {exc}") from exc
        if not np.isfinite(value):
            raise ConvergenceError(f"params: the likelihood is not finite at {_show(natural(theta))}, where the "
                                   f"search went from {_show(natural(theta0))}")
        return value

    h = 1e-5 * np.maximum(1.0, np.abs(theta0))

    def gradient(theta):
        g = np.empty_like(theta)
        for i in range(theta.size):
            e = np.zeros_like(theta)
            e[i] = h[i]
            g[i] = (loglik(theta + e) - loglik(theta - e)) / (2.0 * h[i])
        return g

    trace = [float(first.loglik)]

    def record(intermediate_result):
        trace.append(-float(intermediate_result.fun))

    with one_blas_thread(first.n):      # few-by-few matrices: BLAS's threads would only spin
        opt = scipy.optimize.minimize(lambda t: -loglik(t), theta0, jac=lambda t: -gradient(t), method="L-BFGS-B",
                                      callback=record, options=dict(maxiter=iterations, ftol=tol, gtol=0.0))
        theta, converged = opt.x, bool(opt.success)
        cov_theta, lost = _inverse_information(loglik, theta, names)
    if lost and not converged:
        raise ConvergenceError(f"iterations: the search stopped after {iterations} iterations short of a maximum (at "
                               f"{_show(natural(theta))} the log-likelihood is not concave along {', '.join(lost)}); "
                               "allow more iterations or start closer")
    if lost:
        raise ParameterError(f"params: the data do not determine {', '.join(lost)}: the log-likelihood is flat along "
                             f"{'it' if len(lost) == 1 else 'them'} at the maximum ({_show(natural(theta))}); leave "
                             "such a parameter out of params (fix it in the model function), e.g. a parameter the "
                             "model ignores or a variance whose estimate goes to 0")
    fitted = build(theta)
    scale = np.where(log, np.exp(np.where(log, theta, 0.0)), 1.0)     # d natural / d theta
    cov = cov_theta * np.outer(scale, scale)
    se = np.sqrt(np.diag(cov))
    return FitResult(model=fitted, x0=x0, P0=P0, loglik=np.array(trace), iterations=len(trace) - 1,
                     converged=converged, method="ML", params=natural(theta),
                     stderr=dict(zip(names, se.tolist())), cov=cov)


def _check_params(params):
    if not isinstance(params, Mapping) or not params:
        raise ParameterError(f"params: expected a non-empty mapping of parameter names to starting values, got "
                             f"{params!r}")
    names, values = [], []
    for name, value in params.items():
        if not isinstance(name, str) or not name.isidentifier():
            raise ParameterError(f"params: parameter names must be identifiers, got {name!r}")
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
            raise ParameterError(f"params: {name} must be a finite real number, got {value!r}")
        names.append(name)
        values.append(float(value))
    return tuple(names), np.array(values)


def _positive_mask(positive, names) -> np.ndarray:
    if positive is None:
        return np.ones(len(names), dtype=bool)
    chosen = (positive,) if isinstance(positive, str) else positive
    try:
        chosen = set(chosen)
    except TypeError:
        raise ParameterError(f"positive: expected names of params, got {positive!r}") from None
    unknown = sorted(map(str, chosen - set(names)))
    if unknown:
        raise ParameterError(f"positive: {', '.join(unknown)} not in params {list(names)}")
    return np.array([name in chosen for name in names])


def _inverse_information(loglik, theta, names) -> tuple[np.ndarray | None, list]:
    """(the inverse of the observed information -d2 l / d theta2 at theta, []) (central differences,
    step 1e-3 of each coordinate's scale), or (None, the names of the parameters along which it is not
    positive definite)."""
    k = theta.size
    h = 1e-3 * np.maximum(1.0, np.abs(theta))
    l0 = loglik(theta)
    Hs = np.empty((k, k))
    for i in range(k):
        ei = np.zeros(k)
        ei[i] = h[i]
        Hs[i, i] = (loglik(theta + ei) - 2.0 * l0 + loglik(theta - ei)) / h[i] ** 2
        for j in range(i):
            ej = np.zeros(k)
            ej[j] = h[j]
            Hs[i, j] = Hs[j, i] = (loglik(theta + ei + ej) - loglik(theta + ei - ej) - loglik(theta - ei + ej)
                                   + loglik(theta - ei - ej)) / (4.0 * h[i] * h[j])
    w, U = np.linalg.eigh(-0.5 * (Hs + Hs.T))
    flat = w <= 1e-9 * max(np.abs(w).max(), np.finfo(float).tiny)
    if flat.any():
        return None, [name for name, weight in zip(names, (U[:, flat] ** 2).sum(axis=1)) if weight > 1e-3]
    return (U / w) @ U.T, []


def _show(values: dict) -> str:
    return ", ".join(f"{k}={v:.6g}" for k, v in values.items())

