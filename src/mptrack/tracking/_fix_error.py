"""The error model of a position fix: a white part and a slow part.

Consumer receivers output positions that their own filter has already smoothed, so
the error of a fix against the truth is not white: it changes little from one fix
to the next and wanders over tens of seconds to minutes (multipath, atmosphere,
satellite geometry; stationary receivers show it in their autocorrelation, Soundy
et al. 2020).  Per axis

    z = p + b + v,   v white with variance c w,   db = -b/tau dt + sqrt(2 sb2/tau) dW,

so b is a first-order Gauss-Markov process of stationary variance sb2 and time
constant tau, carried as one more state per axis (the state augmentation for
coloured measurement noise, Gelb 1974).  Between fixes dt apart,
b <- e^(-dt/tau) b plus noise of variance sb2 (1 - e^(-2 dt/tau)).

What the fixes can tell and what they cannot.  The white part shows between fixes,
and its scale c is estimated by maximum likelihood with the motion's q
(:mod:`._noise`).  The slow part cannot be told apart from the motion on a moving
receiver, nor from the position on a log shorter than tau (a 60 s static log): its
level comes from what the input says about the fix's total error, and it is the
part of that total the fixes do not show as white noise:

    sb2 = max(sigma_total^2 - c w, 0),

with sigma_total = the fix's stated accuracy (``accuracy_m``, or 5 m x HDOP: the
reader's convention) where the input has one, else :data:`TOTAL_SIGMA_M` (5 m per
axis, a consumer receiver's error: a mean horizontal error of 6.3 m, within what
smartphones show in cities, Merry & Bettinger 2019).  A receiver that smooths its
output (white part ~0) keeps its whole stated error as the slow part, so the
reported covariance is metres, not the millimetres between its fixes; simulated
white noise whose accuracy states that noise has no slow part left, and the filter
is the white-noise filter.  The time constant is :data:`SLOW_TAU_S`, an hour: on
real logs the fixes' likelihood grows with it from 30 s to an hour and beyond (their
slow error looks constant over the log), so the data do not identify it, and an hour
lets a static receiver's covariance average down only over hours (docs/tracking.md).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from ._registry import DEFAULT_SIGMA_M

__all__ = ["TOTAL_SIGMA_M", "SLOW_TAU_S", "slow_error_variance", "slow_variance"]

#: A fix's total error (1-sigma per axis, m) where the input states none: a consumer receiver's.
TOTAL_SIGMA_M = DEFAULT_SIGMA_M
#: Time constant of the fix error's slow part (s).
SLOW_TAU_S = 3600.0


def slow_error_variance(c: np.ndarray, typical_w: np.ndarray, has_accuracy: np.ndarray) -> np.ndarray:
    """The slow part's stationary variance sb2 (m^2 per axis) of each track: what is left of the total
    error when the white part c w is taken from it (never negative).

    c             (B,) the white part's scale (fix k has white variance c w_k)
    typical_w     (B,) the track's median unit variance w (accuracy^2 where given, else 1 or sigma^2)
    has_accuracy  (B,) the track's fixes state an accuracy: the total is that accuracy (w), else
                  TOTAL_SIGMA_M^2
    """
    c, typical_w, has_accuracy = np.broadcast_arrays(np.asarray(c, float), np.asarray(typical_w, float),
                                                     np.asarray(has_accuracy, bool))
    return _slow_rows(np.ascontiguousarray(c), np.ascontiguousarray(typical_w), np.ascontiguousarray(has_accuracy))


@nb.njit(inline="always")
def slow_variance(c, typical_w, has_accuracy):
    """:func:`slow_error_variance` of one track (for compiled kernels; NaN stays NaN)."""
    x = (typical_w if has_accuracy else TOTAL_SIGMA_M ** 2) - c * typical_w
    return x if x >= 0.0 or x != x else 0.0


@nb.njit(cache=True, nogil=True)
def _slow_rows(c, typical_w, has_accuracy):
    out = np.empty(c.shape)
    for k in range(c.size):
        out.flat[k] = slow_variance(c.flat[k], typical_w.flat[k], has_accuracy.flat[k])
    return out
