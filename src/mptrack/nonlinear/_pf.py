"""The bootstrap particle filter (Gordon, Salmond & Smith 1993) and the large-N reference."""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result
from .._core.validation import as_array, check_allocation, check_int, check_positive, check_rng
from ..errors import ParameterError
from ..result import FilterResult
from .._core.filter_inputs import check_prior, prepare_nonlinear
from .._core.model_families import model_family
from ..models import NonlinearModel
from . import _pf_kernels as kern

__all__ = ["particle_filter", "systematic_resample"]

#: the SDE sub-step scheme of a continuous-discrete model by default (the only value for a NonlinearModel)
_DEFAULT_SCHEME = "rk4-split"


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of N draws by systematic resampling: one uniform u, the N points (u + i)/N.

    Parameters
    ----------
    weights : array_like, shape (N,)
        Finite, >= 0, not all 0 (normalised first).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray of int, shape (N,)

    References
    ----------
    .. [1] G. Kitagawa, "Monte Carlo filter and smoother for non-Gaussian nonlinear state space models", Journal
           of Computational and Graphical Statistics, vol. 5, no. 1, pp. 1–25, 1996.
           doi:10.1080/10618600.1996.10474692
    """
    w = as_array("weights", weights, ndim=1, low=0.0)
    if w.size == 0 or not w.max() > 0:
        raise ParameterError(f"weights: expected non-negative weights, not all zero, got shape {w.shape}"
                             + (f" summing to {w.sum()!r}" if w.size else ""))
    w = w / w.max()
    rng = check_rng(rng)
    return kern.systematic_indices(np.ascontiguousarray(w / w.sum()), rng.random())


@finite_result("the particle filter")
def particle_filter(model, z, x0, P0, rng: np.random.Generator, *,
                    particles: int = 200, ess_threshold: float = 0.5, regularise: bool = False,
                    substeps: int | None = None, scheme: str = "rk4-split", compiled: bool | None = None,
                    prior: str = "initial", method: str = "PF") -> FilterResult:
    """Bootstrap particle filter: propagate by the model, weight by p(z|x), resample when the effective
    sample size is low.

    Estimates are the weighted mean and covariance after the update, before resampling.

    Parameters
    ----------
    model : ContinuousDiscreteModel or NonlinearModel
        An SDE (particles follow it in sub-steps) or a discrete-time model (x = f(x) + w, w ~ N(0, Q); a
        callable Q(x, k) or R(x, k) is evaluated per particle, which is slow).
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped, a NaN row only predicts.
    x0 : array_like, shape (n,)
        The prior mean, required.
    P0 : array_like, shape (n, n)
        The prior covariance, required.
    rng : numpy.random.Generator
        The random generator.
    particles : int, optional
        Number of particles N.
    ess_threshold : float, optional
        Resample (systematically) when 1/sum(w^2) falls below ess_threshold N (1: every step, 0: never).
    regularise : bool, optional
        After resampling, jitter the particles with a Gaussian kernel of covariance h^2 (weighted
        covariance), h the Silverman bandwidth (Musso et al. 2001).
    substeps : int, optional
        Continuous-discrete models: sub-steps per dt (default :func:`mptrack.continuous.pf_substeps`).
    scheme : {"rk4-split", "heun"}, optional
        Continuous-discrete models: the SDE sub-step scheme.
    compiled : bool, optional
        None: the model's compiled kernels when it has them, else NumPy; False: NumPy; True: require the
        kernels.  Both paths draw the same numbers.
    prior : {"initial", "first-measurement"}, optional
        x0, P0 at time 0 (predicted to the first measurement), or the prior at the first measurement.
    method : str, optional
        The result's method name.

    Returns
    -------
    FilterResult

    References
    ----------
    .. [1] N. J. Gordon, D. J. Salmond and A. F. M. Smith, "Novel approach to nonlinear/non-Gaussian Bayesian
           state estimation", IEE Proceedings F, vol. 140, no. 2, pp. 107–113, 1993.
           doi:10.1049/ip-f-2.1993.0015
    .. [2] G. Kitagawa, "Monte Carlo filter and smoother for non-Gaussian nonlinear state space models", Journal
           of Computational and Graphical Statistics, vol. 5, no. 1, pp. 1–25, 1996.
           doi:10.1080/10618600.1996.10474692
    .. [3] C. Musso, N. Oudjane and F. Le Gland, "Improving regularised particle filters", in A. Doucet, N. de
           Freitas and N. Gordon (eds.), Sequential Monte Carlo Methods in Practice, Springer, pp. 247–271,
           2001.
    """
    first = check_prior(prior)
    default_substeps = substeps is None
    z, m0, P0, substeps = prepare_nonlinear(model, z, x0, P0, substeps)
    discrete = isinstance(model, NonlinearModel)
    if discrete and not (isinstance(scheme, str) and scheme == _DEFAULT_SCHEME):
        raise ParameterError(f"scheme: only for a continuous-discrete model (a NonlinearModel is discrete-time), "
                             f"got {scheme!r}")
    rng = check_rng(rng)
    N = check_int("particles", particles, minimum=2)
    check_allocation("particles", N, 8.0 * N * (4 * model.n + 4))
    thr = check_positive("ess_threshold", ess_threshold, allow_zero=True)
    if thr > 1:
        raise ParameterError(f"ess_threshold: expected a number in [0, 1], got {ess_threshold!r}")
    if discrete:
        if compiled:
            raise ParameterError("compiled: the model has no compiled kernels (BlockKernels)")

        def propagate(X, k):
            return model.sample_transition(X, rng, k)

        def log_likelihood(zk, X, k):
            return model.log_likelihood(zk, X, k)
    else:
        propagate, log_likelihood = model_family(model).pf(
            model, rng, substeps=None if default_substeps else substeps, scheme=scheme, compiled=compiled)
    n, T = model.n, z.shape[0]
    w0, V = np.linalg.eigh(P0)
    L0 = V * np.sqrt(np.clip(w0, 0.0, None))
    X = m0 + rng.standard_normal((N, n)) @ L0.T
    logw, w = np.full(N, -np.log(N)), np.full(N, 1.0 / N)
    bandwidth = (N * (n + 2) / 4.0) ** (-1.0 / (n + 4))
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    xp, Pp = np.empty((T, n)), np.empty((T, n, n))
    loglik = 0.0
    for k in range(T):
        if not (first and k == 0):
            X = np.ascontiguousarray(propagate(X, k))
        xp[k], Pp[k], ess = kern.weighted_moments(X, w)
        if not np.isnan(z[k]).all():
            increment = kern.reweight(logw, w, log_likelihood(z[k], X, k))
            if not np.isfinite(increment):
                raise ParameterError(f"z: measurement {k} has zero likelihood under every particle")
            loglik += increment
            xs[k], Ps[k], ess = kern.weighted_moments(X, w)
        else:
            xs[k], Ps[k] = xp[k], Pp[k]
        if ess < thr * N:
            X = kern.resample(X, w, rng.random())
            logw.fill(-np.log(N))
            w.fill(1.0 / N)
            if regularise:
                L = np.linalg.cholesky(Ps[k] + 1e-12 * np.trace(Ps[k]) * np.eye(n))
                X = X + bandwidth * (rng.standard_normal((N, n)) @ L.T)
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method=method,
                        x0=None if first else m0, P0=None if first else P0)
