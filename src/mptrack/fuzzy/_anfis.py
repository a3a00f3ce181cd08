"""ANFIS hybrid learning of a zero-order Takagi–Sugeno system (Jang 1993, IEEE Trans. SMC 23(3), §IV).

Each epoch: (1) with the premise (membership) parameters fixed, the rule
constants c solve the (optionally box-bounded) linear least-squares problem  min ||W_bar c - y||  where
W_bar holds the normalised firing strengths (forward pass); (2) with c fixed,
the premise parameters take a gradient step on E = 1/2 sum (y_hat - y)^2
(backward pass), with Jang's step-size heuristic reduced to: grow the step by
10 % after a decrease of E, halve it and undo the step after an increase.

Membership functions are Gaussian (smooth gradients, as in Jang's ANFIS);
each input is scaled to [0, 1] over its universe for training, and the
result is returned as an ordinary :class:`TakagiSugeno` in the input's units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

from .._validation import as_array, check_int, check_positive
from ..errors import ParameterError, ShapeError
from ._membership import MembershipFunction
from ._ts import TakagiSugeno

__all__ = ["AnfisResult", "anfis_train"]


@dataclass(frozen=True, eq=False)
class AnfisResult:
    """A trained system, its training RMSE per epoch (epochs + 1 values, the first before training)."""

    fis: TakagiSugeno
    rmse: np.ndarray


def _forward(u, means, sigmas):
    """Memberships per input (list of (N, n_j)) and grid firing strengths (N, n_1, ..., n_p)."""
    mus = [np.exp(-0.5 * ((u[:, j, None] - means[j]) / sigmas[j]) ** 2) for j in range(u.shape[1])]
    w = mus[0]
    for mu in mus[1:]:
        w = w[..., None] * mu.reshape(mu.shape[:1] + (1,) * (w.ndim - 1) + mu.shape[1:])
    return mus, w


def _consequents(w, y, ridge, bounds):
    N = w.shape[0]
    wbar = (w / w.reshape(N, -1).sum(axis=1).reshape((N,) + (1,) * (w.ndim - 1))).reshape(N, -1)
    A = np.vstack([wbar, np.sqrt(ridge) * np.eye(wbar.shape[1])])
    b = np.concatenate([y, np.zeros(wbar.shape[1])])
    if bounds is None:
        c = np.linalg.lstsq(A, b, rcond=None)[0]
    else:
        c = lsq_linear(A, b, bounds=bounds, method="bvls").x
    return c.reshape(w.shape[1:])


def _predict(w, c):
    N = w.shape[0]
    return (w * c).reshape(N, -1).sum(axis=1) / w.reshape(N, -1).sum(axis=1)


def _premise_gradient(u, means, sigmas, c, y):
    """Gradient of E/N = mean of 1/2 (y_hat - y)^2 w.r.t. the Gaussian means and sigmas (c fixed)."""
    N, p = u.shape
    _, w = _forward(u, means, sigmas)
    total = w.reshape(N, -1).sum(axis=1)
    yhat = _predict(w, c)
    shape = (N,) + (1,) * p
    g = ((yhat - y) / total).reshape(shape) * (c - yhat.reshape(shape)) * w  # dE/dw_r * w_r
    grad_m, grad_s = [], []
    for j in range(p):
        gj = g.sum(axis=tuple(a for a in range(1, p + 1) if a != j + 1))  # (N, n_j)
        d = u[:, j, None] - means[j]
        grad_m.append((gj * d / sigmas[j] ** 2).sum(axis=0) / N)
        grad_s.append((gj * d ** 2 / sigmas[j] ** 3).sum(axis=0) / N)
    return grad_m, grad_s


def anfis_train(inputs, target, *, sets_per_input, universes, epochs: int = 40, learning_rate: float = 0.05,
                ridge: float = 1e-6, bounds: tuple[float, float] | None = None, names=None) -> AnfisResult:
    """Train a zero-order TS system on (inputs (N, p), target (N,)) by ANFIS hybrid learning.

    sets_per_input  number of fuzzy sets per input, e.g. (5, 2) for the paper's Table I
    universes       per input (lo, hi): inputs are clipped to it (as the TS system does at run time)
                    and the initial sets are a uniform Gaussian partition of it
    ridge           Tikhonov weight on the rule constants (keeps rules no sample fires near 0)
    bounds          (lo, hi) box for the rule constants, solved by bounded least squares
                    (scipy.optimize.lsq_linear); e.g. (0, 1) for weights as in the paper (c_j in [0, 1])
    Deterministic: the same data give the same system.
    """
    x = as_array("inputs", inputs, ndim=2)
    y = as_array("target", target, ndim=1)
    if x.shape[0] != y.shape[0] or x.shape[0] == 0:
        raise ShapeError(f"inputs, target: need the same number (> 0) of samples, got {x.shape[0]} and {y.shape[0]}")
    p = x.shape[1]
    counts = tuple(check_int("sets_per_input", c, minimum=2) for c in sets_per_input)
    if len(counts) != p or len(universes) != p:
        raise ShapeError(f"sets_per_input, universes: expected {p} entries (one per input column)")
    epochs = check_int("epochs", epochs, minimum=0)
    eta = check_positive("learning_rate", learning_rate)
    lo = np.array([u[0] for u in universes], dtype=float)
    hi = np.array([u[1] for u in universes], dtype=float)
    if np.any(hi <= lo):
        raise ParameterError(f"universes: need lo < hi for every input, got {universes}")
    u = (np.clip(x, lo, hi) - lo) / (hi - lo)
    means = [np.linspace(0.0, 1.0, c) for c in counts]
    sigmas = [np.full(c, 0.5 / (c - 1)) for c in counts]

    def loss(means, sigmas):
        _, w = _forward(u, means, sigmas)
        c = _consequents(w, y, ridge, bounds)
        err = _predict(w, c) - y
        return float(np.sqrt(np.mean(err ** 2))), w, c, err

    history = []
    current, w, c, _ = loss(means, sigmas)
    history.append(current)
    for _ in range(epochs):
        grad_m, grad_s = _premise_gradient(u, means, sigmas, c, y)
        new_means = [m - eta * g for m, g in zip(means, grad_m)]
        new_sigmas = [np.maximum(s - eta * g, 1e-3) for s, g in zip(sigmas, grad_s)]
        trial, _, c_t, _ = loss(new_means, new_sigmas)
        if trial <= current:
            means, sigmas, current, c = new_means, new_sigmas, trial, c_t
            eta *= 1.1
        else:
            eta *= 0.5
        history.append(current)

    sets = tuple(
        tuple(MembershipFunction("gaussian", (lo[j] + m * (hi[j] - lo[j]), s * (hi[j] - lo[j])), f"A{j}{i}")
              for i, (m, s) in enumerate(zip(means[j], sigmas[j])))
        for j in range(p))
    fis = TakagiSugeno(sets, c, universes=tuple((float(lo[j]), float(hi[j])) for j in range(p)), names=names)
    return AnfisResult(fis=fis, rmse=np.array(history))
