"""Compiled kernels of the bootstrap particle filter for any model: the Bayes reweighting, the weighted
moments of the particles and systematic resampling (:func:`mptrack.nonlinear.particle_filter`; they were
in mptrack/continuous/_kernels.py, but nothing in them is continuous-discrete)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory

__all__ = ["reweight", "weighted_moments", "systematic_indices", "resample"]


@njit(cache=True, nogil=True)
def reweight(logw, w, ll):  # pragma: no cover - compiled
    """Bayes update of normalised log-weights and weights, in place: logw <- logw + ll - log Σ exp(logw + ll),
    w = exp(logw).  Returns log Σ exp(logw + ll), the measurement's log-likelihood increment (-inf, and
    nothing changed, if every particle has zero likelihood)."""
    N = logw.shape[0]
    a_max = -np.inf
    for i in range(N):
        a = logw[i] + ll[i]
        if a > a_max:
            a_max = a
    if not np.isfinite(a_max):
        return -np.inf
    total = 0.0
    for i in range(N):
        logw[i] = logw[i] + ll[i] - a_max
        w[i] = np.exp(logw[i])
        total += w[i]
    lt = np.log(total)
    for i in range(N):
        w[i] /= total
        logw[i] -= lt
    return a_max + lt


@njit(cache=True, nogil=True)
def _wsum(w, X, r, c, m_r, m_c):  # pragma: no cover - compiled
    """Σ_i w_i (X[i, r] - m_r)(X[i, c] - m_c), or Σ_i w_i X[i, r] if c < 0, or Σ_i w_i² if r < 0; in four
    interleaved partial sums (lane i mod 4; a fixed order, so deterministic; four add chains instead of
    one latency-bound chain)."""
    N = w.shape[0]
    N4 = N - N % 4
    s0 = s1 = s2 = s3 = 0.0
    if r < 0:
        for i in range(0, N4, 4):
            s0 += w[i] * w[i]
            s1 += w[i + 1] * w[i + 1]
            s2 += w[i + 2] * w[i + 2]
            s3 += w[i + 3] * w[i + 3]
        for i in range(N4, N):
            s0 += w[i] * w[i]
    elif c < 0:
        for i in range(0, N4, 4):
            s0 += w[i] * X[i, r]
            s1 += w[i + 1] * X[i + 1, r]
            s2 += w[i + 2] * X[i + 2, r]
            s3 += w[i + 3] * X[i + 3, r]
        for i in range(N4, N):
            s0 += w[i] * X[i, r]
    else:
        for i in range(0, N4, 4):
            s0 += w[i] * (X[i, r] - m_r) * (X[i, c] - m_c)
            s1 += w[i + 1] * (X[i + 1, r] - m_r) * (X[i + 1, c] - m_c)
            s2 += w[i + 2] * (X[i + 2, r] - m_r) * (X[i + 2, c] - m_c)
            s3 += w[i + 3] * (X[i + 3, r] - m_r) * (X[i + 3, c] - m_c)
        for i in range(N4, N):
            s0 += w[i] * (X[i, r] - m_r) * (X[i, c] - m_c)
    return (s0 + s1) + (s2 + s3)


@njit(cache=True, nogil=True)
def weighted_moments(X, w):  # pragma: no cover - compiled
    """Mean, covariance (symmetric, two-pass) and effective sample size 1/Σw² of the particles X (N, n)
    with normalised weights w."""
    n = X.shape[1]
    m = np.empty(n)
    for r in range(n):
        m[r] = _wsum(w, X, r, -1, 0.0, 0.0)
    P = np.empty((n, n))
    for r in range(n):
        for c in range(r + 1):
            P[r, c] = _wsum(w, X, r, c, m[r], m[c])
            P[c, r] = P[r, c]
    return m, P, 1.0 / _wsum(w, X, -1, -1, 0.0, 0.0)


@njit(cache=True, nogil=True)
def systematic_indices(weights, u):  # pragma: no cover - compiled
    """Indices of systematic resampling with the offset u in [0, 1): draw i takes the first j with
    cdf[j] > t_i = (u + i)/N, i.e. ``np.searchsorted(cdf, t, side="right")`` with the running sum
    capped at 1 (rounding can push it past 1 before the end), cdf[-1] = 1, and the index capped at
    N - 1 (t_i can round to 1 when u is within 1e-16 of 1).

    Without a data-dependent branch per draw (those mispredict): k_j = #{i: t_i < cdf[j]} from
    ceil(N cdf[j] - u), corrected against the exact comparison, then idx[i] = #{j: k_j <= i} by a
    histogram of k and its running sum."""
    N = weights.shape[0]
    hist = np.zeros(N + 1, np.int64)
    c = 0.0
    for j in range(N):
        c = min(c + weights[j], 1.0) if j < N - 1 else 1.0
        k = min(max(np.ceil(c * N - u), 0.0), float(N))
        k = int(k)
        while k > 0 and (u + (k - 1)) / N >= c:
            k -= 1
        while k < N and (u + k) / N < c:
            k += 1
        hist[k] += 1
    idx = np.empty(N, np.int64)
    run = 0
    for i in range(N):
        run += hist[i]
        idx[i] = min(run, N - 1)
    return idx


@njit(cache=True, nogil=True)
def resample(X, w, u):  # pragma: no cover - compiled
    """The particles X[systematic_indices(w, u)] (a new array)."""
    idx = systematic_indices(w, u)
    N, n = X.shape
    out = np.empty_like(X)
    for i in range(N):
        for r in range(n):
            out[i, r] = X[idx[i], r]
    return out
