"""Gaussian measurement noise shared by the model families (mptrack.models, mptrack.continuous):
innovations with angle components wrapped into one period, and the Gaussian log-density of innovations."""

from __future__ import annotations

import numpy as np

__all__ = ["LOG2PI", "wrap_periods", "gauss_logpdf"]

LOG2PI = np.log(2.0 * np.pi)


def wrap_periods(nu, periods: tuple) -> np.ndarray:
    """A copy of ``nu`` (..., m) with each component i whose ``periods[i]`` is not None wrapped into
    [-period/2, period/2) (no validation: the filters' innovations; the checked form is
    :func:`mptrack.models.wrap_angles`)."""
    nu = np.array(nu, dtype=float)
    for i, period in enumerate(periods):
        if period is not None:
            nu[..., i] = (nu[..., i] + 0.5 * period) % period - 0.5 * period
    return nu


def gauss_logpdf(nu: np.ndarray, R: np.ndarray):
    """log N(nu; 0, R) for innovations nu (..., m)."""
    L = np.linalg.cholesky(R)
    w = nu @ np.linalg.inv(L).T
    return -0.5 * (np.sum(w * w, axis=-1) + 2.0 * np.log(np.diag(L)).sum() + R.shape[0] * LOG2PI)
