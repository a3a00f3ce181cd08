"""The bootstrap particle filter (Gordon, Salmond & Smith 1993) and the large-N reference."""

from __future__ import annotations

import numpy as np

from .._validation import check_int, check_positive
from ..errors import ParameterError
from ..linear import FilterResult
from ._common import check_rng, prepare_nonlinear
from ._model import ContinuousDiscreteModel

__all__ = ["particle_filter", "systematic_resample"]


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of N draws by systematic resampling (one uniform, N evenly spaced points)."""
    N = weights.shape[0]
    cdf = np.cumsum(weights)
    cdf[-1] = 1.0
    u = (rng.random() + np.arange(N)) / N
    return np.searchsorted(cdf, u, side="right")


def _weighted_moments(X: np.ndarray, w: np.ndarray):
    m = w @ X
    D = X - m
    P = (w[:, None] * D).T @ D
    return m, 0.5 * (P + P.T)


def particle_filter(model: ContinuousDiscreteModel, z, x0, P0, rng: np.random.Generator, *,
                    particles: int = 200, ess_threshold: float = 0.5, regularise: bool = False,
                    substeps: int | None = None, method: str = "PF") -> FilterResult:
    """Bootstrap particle filter: propagate by the SDE, weight by p(z|x), resample when ESS is low.

    particles      number of particles N
    ess_threshold  resample (systematically) when the effective sample size
                   1/Σw² falls below ess_threshold·N (1 = every step, 0 = never)
    regularise     after resampling, jitter the particles with a Gaussian kernel
                   whose covariance is h²·(weighted covariance), h the Silverman
                   bandwidth (N(n+2)/4)^(-1/(n+4)) (regularised PF, Musso et al. 2001)
    substeps       tamed Euler–Maruyama sub-steps per dt (default model.substeps)
    Estimates are the weighted mean/covariance after the update, before resampling.
    """
    z, m0, P0, substeps = prepare_nonlinear(model, z, x0, P0, substeps)
    rng = check_rng(rng)
    N = check_int("particles", particles, minimum=2)
    thr = check_positive("ess_threshold", ess_threshold, allow_zero=True)
    if thr > 1:
        raise ParameterError(f"ess_threshold: expected a number in [0, 1], got {ess_threshold!r}")
    n, T = model.n, z.shape[0]
    w0, V = np.linalg.eigh(P0)
    L0 = V * np.sqrt(np.clip(w0, 0.0, None))
    X = m0 + rng.standard_normal((N, n)) @ L0.T
    logw = np.full(N, -np.log(N))
    bandwidth = (N * (n + 2) / 4.0) ** (-1.0 / (n + 4))
    xs, Ps = np.empty((T, n)), np.empty((T, n, n))
    xp, Pp = np.empty((T, n)), np.empty((T, n, n))
    loglik = 0.0
    for k in range(T):
        X = model.sample_transition(X, rng, substeps)
        w = np.exp(logw - logw.max())
        w /= w.sum()
        xp[k], Pp[k] = _weighted_moments(X, w)
        if not np.isnan(z[k]).all():
            ll = model.log_likelihood(z[k], X)
            a = logw + ll
            amax = a.max()
            if not np.isfinite(amax):
                raise ParameterError(f"z: measurement {k} has zero likelihood under every particle")
            total = amax + np.log(np.exp(a - amax).sum())
            loglik += total - (logw.max() + np.log(np.exp(logw - logw.max()).sum()))
            logw = a - total
        w = np.exp(logw)
        xs[k], Ps[k] = _weighted_moments(X, w)
        if 1.0 / np.sum(w * w) < thr * N:
            X = X[systematic_resample(w, rng)]
            logw = np.full(N, -np.log(N))
            if regularise:
                L = np.linalg.cholesky(Ps[k] + 1e-12 * np.trace(Ps[k]) * np.eye(n))
                X = X + bandwidth * (rng.standard_normal((N, n)) @ L.T)
    return FilterResult(x=xs, P=Ps, x_pred=xp, P_pred=Pp, loglik=float(loglik), method=method)
