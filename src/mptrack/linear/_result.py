"""The result record shared by every filter in mptrack."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FilterResult"]


@dataclass(frozen=True, eq=False)
class FilterResult:
    """Output of a filter run over T measurement times.

    x       (T, n)     filtered means x(k/k), k = 1..T
    P       (T, n, n)  filtered covariances P(k/k)
    x_pred  (T, n)     predicted means x(k/k-1), where the algorithm forms them (else None)
    P_pred  (T, n, n)  predicted covariances P(k/k-1) (else None)
    loglik  log-likelihood of the measurements (Kalman-type filters; else None)
    method  the filter's registry name ("KF", "LF", "SSKF", ...)
    x0, P0  a filter's prior x(0/0), P(0/0) at time 0, or a smoother's x(0/T), P(0/T);
            None when the prior was given at the first measurement (or not recorded)
    inputs  what the filter ran with besides the model that its smoother must reuse, or None:
            kalman_filter's per-step {"F", "Q" (T, n, n), "Bu" (T, n) or None} of a time-varying or
            controlled run (read by rts_smoother), ukf_filter's {"alpha", "beta", "kappa"}
            (read by ukf_smoother)
    """

    x: np.ndarray
    P: np.ndarray
    x_pred: np.ndarray | None = None
    P_pred: np.ndarray | None = None
    loglik: float | None = None
    method: str = ""
    x0: np.ndarray | None = None
    P0: np.ndarray | None = None
    inputs: dict | None = None

    @property
    def T(self) -> int:
        return self.x.shape[0]

    @property
    def n(self) -> int:
        return self.x.shape[1]
