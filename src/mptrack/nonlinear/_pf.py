"""The bootstrap particle filter (Gordon, Salmond & Smith 1993) and the large-N reference."""

from __future__ import annotations

import numpy as np

from .._validation import check_int, check_positive, check_allocation, finite_result
from ..errors import ParameterError, ShapeError
from ..linear import FilterResult
from ..continuous import _kernels as kern
from ..continuous._kernels import SCHEMES
from ..continuous._model import ContinuousDiscreteModel
from ..models import NonlinearModel
from ._common import check_prior, check_rng, prepare_nonlinear

__all__ = ["particle_filter", "systematic_resample", "pf_substeps"]

#: default sub-steps of the "rk4-split" scheme (docs/nonlinear.md, study on eq. 42): at least
#: model.substeps / SPLIT_RATIO (2 for the usual 20 per second: the bias of the 2-step split on
#: the Q x 0.01 example is a third of the Monte-Carlo error of 10^4 particles), and enough that the
#: noise per sub-step, sqrt(tr(Q) h), is at most NOISE_STEP state units (the weak error grows
#: with it: Q x 0.1 needs 4-5 sub-steps, Q x 1 about 20-40)
SPLIT_RATIO = 10
NOISE_STEP = 0.5


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of N draws by systematic resampling (one uniform u, the N points (u + i)/N)."""
    w = np.ascontiguousarray(weights, dtype=float)
    if w.ndim != 1 or w.size == 0:
        raise ShapeError(f"weights: expected a non-empty vector, got shape {w.shape}")
    return kern.systematic_indices(w, rng.random())


def pf_substeps(model: ContinuousDiscreteModel, scheme: str = "rk4-split") -> int:
    """The particle filter's default sub-steps per dt: model.substeps for "heun"; for "rk4-split"
    max(ceil(model.substeps / SPLIT_RATIO), ceil(tr(Q)·dt / NOISE_STEP²)) (2 for eq. 42 with
    Q x 0.01, 5 with Q x 0.1, 41 with Q x 1)."""
    if scheme not in SCHEMES:
        raise ParameterError(f"scheme: expected one of {SCHEMES}, got {scheme!r}")
    if scheme == "heun":
        return model.substeps
    noise = int(np.ceil(np.trace(model.Q) * model.dt / NOISE_STEP ** 2 - 1e-12))
    return max(-(-model.substeps // SPLIT_RATIO), noise)


@finite_result("the particle filter")
def particle_filter(model, z, x0, P0, rng: np.random.Generator, *,
                    particles: int = 200, ess_threshold: float = 0.5, regularise: bool = False,
                    substeps: int | None = None, scheme: str = "rk4-split", compiled: bool | None = None,
                    prior: str = "initial", method: str = "PF") -> FilterResult:
    """Bootstrap particle filter: propagate by the model, weight by p(z|x), resample when ESS is low.

    model          a :class:`ContinuousDiscreteModel` (particles follow the SDE in sub-steps) or a
                   discrete-time :class:`mptrack.models.NonlinearModel` (x = f(x) + w, w ~ N(0, Q);
                   a callable Q(x, k) or R(x, k) is evaluated per particle, which is slow)
    prior          "initial" (x0, P0 at time 0) or "first-measurement" (no propagation before it)

    particles      number of particles N
    ess_threshold  resample (systematically) when the effective sample size
                   1/Σw² falls below ess_threshold·N (1 = every step, 0 = never)
    regularise     after resampling, jitter the particles with a Gaussian kernel
                   whose covariance is h²·(weighted covariance), h the Silverman
                   bandwidth (N(n+2)/4)^(-1/(n+4)) (regularised PF, Musso et al. 2001)
    scheme         SDE sub-step scheme of :meth:`ContinuousDiscreteModel.sample_transition`:
                   "rk4-split" (default; RK4 drift flows around the noise) or "heun"
    substeps       sub-steps per dt (default :func:`pf_substeps`: 2 for eq. 42 with Q x 0.01,
                   more when the diffusion is large); continuous-discrete models only
    compiled       None: use the model's compiled kernels when it has them (zhao2013_model,
                   linear_sde_model), else NumPy; False: NumPy; True: require the kernels.
                   Both paths draw the same numbers and give the same result up to rounding.
    Estimates are the weighted mean/covariance after the update, before resampling.
    """
    if scheme not in SCHEMES:
        raise ParameterError(f"scheme: expected one of {SCHEMES}, got {scheme!r}")
    first = check_prior(prior)
    default_substeps = substeps is None
    z, m0, P0, substeps = prepare_nonlinear(model, z, x0, P0, substeps)
    discrete = isinstance(model, NonlinearModel)
    if default_substeps and not discrete:
        substeps = pf_substeps(model, scheme)
    rng = check_rng(rng)
    N = check_int("particles", particles, minimum=2)
    check_allocation("particles", N, 8.0 * N * (4 * model.n + 4))
    thr = check_positive("ess_threshold", ess_threshold, allow_zero=True)
    if thr > 1:
        raise ParameterError(f"ess_threshold: expected a number in [0, 1], got {ess_threshold!r}")
    kernels = None if discrete else model.kernels
    if compiled and kernels is None:
        raise ParameterError("compiled: the model has no compiled kernels (BlockKernels)")
    use_kernels = kernels is not None if compiled is None else bool(compiled)
    if discrete:
        def propagate(X, k):
            return model.sample_transition(X, rng, k)

        def log_likelihood(zk, X, k):
            return model.log_likelihood(zk, X, k)
    else:
        if use_kernels:
            compiled_model = kern.compiled_model(model)
            advance, weigh = compiled_model.propagate, compiled_model.log_likelihood
        else:
            advance, weigh = model.sample_transition, model.log_likelihood

        def propagate(X, k):
            return advance(X, rng, substeps, scheme)

        def log_likelihood(zk, X, k):
            return weigh(zk, X)
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
