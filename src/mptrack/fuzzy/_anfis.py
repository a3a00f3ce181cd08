"""ANFIS hybrid learning of a zero-order Takagi–Sugeno system (Jang 1993, IEEE Trans. SMC 23(3), §IV).

Each epoch: (1) with the premise (membership) parameters fixed, the rule
constants c solve the (optionally box-bounded) linear least-squares problem  min ||W_bar c - y||  where
W_bar holds the normalised firing strengths (forward pass); (2) with c fixed,
the premise parameters take a gradient step of length kappa on E = 1/2 sum (y_hat - y)^2 (backward pass:
Jang's normalised step, Delta = -kappa g / ||g|| over all premise parameters), with his step-size
heuristic reduced to: grow kappa by 10 % after a decrease of E, halve it and undo the step after an
increase.

Membership functions are Gaussian (mean, sigma; smooth gradients, as in Jang's ANFIS) or triangular
(feet a, c and peak b, as MATLAB's ``trimf``, which Bouzera et al. 2017 chose; the gradient is taken on
each linear piece).  Each input is scaled to [0, 1] over its universe for training; the initial sets are
evenly spaced (triangles with their feet at the neighbouring peaks, MATLAB's ``genfis1`` grid).  A
triangular step that would leave part of a universe where no set fires is refused like a step that
increases E.  The result is returned as an ordinary :class:`TakagiSugeno` in the input's units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

from .._core.validation import as_array, check_int, check_positive
from ..errors import ParameterError, ShapeError
from ._membership import MembershipFunction
from ._ts import TakagiSugeno

__all__ = ["AnfisResult", "anfis_train"]

_MIN_WIDTH = 1e-3  # smallest sigma, or triangle side, in the scaled [0, 1] units


@dataclass(frozen=True, eq=False)
class AnfisResult:
    """A trained system, its training RMSE per epoch (epochs + 1 values, the first before training)."""

    fis: TakagiSugeno
    rmse: np.ndarray


def _membership(x, p, kind):
    """Memberships (N, n) of the column x (N,) in the n sets with parameters p (n, 2 | 3), and their
    derivatives (N, n, 2 | 3) with respect to the parameters."""
    x = x[:, None]
    if kind == "gaussian":
        m, s = p[:, 0], p[:, 1]
        d = x - m
        mu = np.exp(-0.5 * (d / s) ** 2)
        return mu, np.stack([mu * d / s ** 2, mu * d ** 2 / s ** 3], axis=-1)
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    rise = (x > a) & (x <= b)
    fall = (x > b) & (x < c)
    left, right = b - a, c - b
    mu = np.where(rise, (x - a) / left, 0.0) + np.where(fall, (c - x) / right, 0.0)
    da = np.where(rise, (x - b) / left ** 2, 0.0)
    db = np.where(rise, -(x - a) / left ** 2, 0.0) + np.where(fall, (c - x) / right ** 2, 0.0)
    dc = np.where(fall, (x - b) / right ** 2, 0.0)
    return mu, np.stack([da, db, dc], axis=-1)


def _forward(u, params, kind):
    """Memberships and their derivatives per input, and the grid firing strengths (N, n_1, ..., n_p)."""
    mus, dmus = zip(*(_membership(u[:, j], params[j], kind) for j in range(u.shape[1])))
    w = mus[0]
    for mu in mus[1:]:
        w = w[..., None] * mu.reshape(mu.shape[:1] + (1,) * (w.ndim - 1) + mu.shape[1:])
    return mus, dmus, w


def _consequents(w, y, ridge, bounds):
    N = w.shape[0]
    wbar = (w / w.reshape(N, -1).sum(axis=1).reshape((N,) + (1,) * (w.ndim - 1))).reshape(N, -1)
    A = np.vstack([wbar, np.sqrt(ridge) * np.eye(wbar.shape[1])])
    b = np.concatenate([y, np.zeros(wbar.shape[1])])
    if bounds is None:
        c = np.linalg.lstsq(A, b, rcond=None)[0]
    else:  # ||A c - b||^2 = ||L^T c - L^-1 A^T b||^2 + const (A^T A = L L^T): the bounded problem, made small
        L = np.linalg.cholesky(A.T @ A)
        c = lsq_linear(L.T, np.linalg.solve(L, A.T @ b), bounds=bounds, method="bvls").x
    return c.reshape(w.shape[1:])


def _predict(w, c):
    N = w.shape[0]
    return (w * c).reshape(N, -1).sum(axis=1) / w.reshape(N, -1).sum(axis=1)


def _premise_gradient(u, params, kind, c, y):
    """Gradient of E/N = mean of 1/2 (y_hat - y)^2 w.r.t. each input's membership parameters (c fixed)."""
    N, p = u.shape
    mus, dmus, w = _forward(u, params, kind)
    total = w.reshape(N, -1).sum(axis=1)
    yhat = _predict(w, c)
    shape = (N,) + (1,) * p
    g = ((yhat - y) / (N * total)).reshape(shape) * (c - yhat.reshape(shape))  # dE/dw_r
    grads = []
    for j in range(p):
        gj = g
        for k in range(p):
            if k != j:  # dw_r / dmu_j = product of the other inputs' memberships
                gj = gj * mus[k].reshape((N,) + tuple(mus[k].shape[1] if a == k else 1 for a in range(p)))
        gj = gj.sum(axis=tuple(a + 1 for a in range(p) if a != j))  # (N, n_j)
        grads.append(np.einsum("ni,nik->ik", gj, dmus[j]))
    return grads


def _initial(count, kind):
    peaks = np.linspace(0.0, 1.0, count)
    step = 1.0 / (count - 1)
    if kind == "gaussian":
        return np.column_stack([peaks, np.full(count, 0.5 * step)])
    return np.column_stack([peaks - step, peaks, peaks + step])


def _covers(a, c) -> bool:
    """Whether the open supports (a_i, c_i) of the triangles cover [0, 1]."""
    reach = max((ci for ai, ci in zip(a, c) if ai < 0.0), default=0.0)
    while 0.0 < reach <= 1.0:
        further = max(ci for ai, ci in zip(a, c) if ai < reach)
        if further <= reach:
            return False
        reach = further
    return reach > 1.0


def _valid(p, kind):
    """A step's parameters put back into shape (ordered corners, a minimum width); None when the
    triangles no longer cover [0, 1] (some input value would fire no rule)."""
    if kind == "gaussian":
        return np.column_stack([p[:, 0], np.maximum(p[:, 1], _MIN_WIDTH)])
    a, b, c = np.sort(p, axis=1).T
    a, c = np.minimum(a, b - _MIN_WIDTH), np.maximum(c, b + _MIN_WIDTH)
    return np.column_stack([a, b, c]) if _covers(a, c) else None


def anfis_train(inputs, target, *, sets_per_input, universes, epochs: int = 40, learning_rate: float = 0.01,
                ridge: float = 1e-6, bounds: tuple[float, float] | None = None, names=None,
                membership: str = "gaussian") -> AnfisResult:
    """Train a zero-order Takagi-Sugeno system by ANFIS hybrid learning (Jang 1993).

    Deterministic: the same data give the same system.

    Parameters
    ----------
    inputs : array_like, shape (N, p)
    target : array_like, shape (N,)
    sets_per_input : sequence of int
        Fuzzy sets per input, e.g. (5, 2) for the paper's Table I.
    universes : sequence of (float, float)
        Per input (lo, hi): inputs are clipped to it, and the initial sets partition it evenly.
    epochs : int, optional
    learning_rate : float, optional
        Jang's initial step size kappa, the length of the first premise step in units of the universes
        (scaled to [0, 1]).
    ridge : float, optional
        Tikhonov weight on the rule constants (keeps rules no sample fires near 0).
    bounds : tuple of float, optional
        (lo, hi) box for the rule constants, solved by bounded least squares; (0, 1) for weights as in
        the paper.
    names : sequence of str, optional
        The inputs' names.
    membership : {"gaussian", "triangular"}, optional
        The shape of every set.

    Returns
    -------
    AnfisResult
        The trained system and its training error per epoch.

    References
    ----------
    .. [1] J.-S. R. Jang, "ANFIS: adaptive-network-based fuzzy inference system", IEEE Transactions on Systems,
           Man, and Cybernetics, vol. 23, no. 3, pp. 665–685, 1993. doi:10.1109/21.256541
    .. [2] N. Bouzera, M. Oussalah, N. Mezhoud and A. Khireddine, "Fuzzy extended Kalman filter for dynamic
           mobile localization in urban area using wireless network", Applied Soft Computing, vol. 57, pp.
           452–467, 2017. doi:10.1016/j.asoc.2017.04.007
    """
    x = as_array("inputs", inputs, ndim=2)
    y = as_array("target", target, ndim=1)
    if x.shape[0] != y.shape[0] or x.shape[0] == 0:
        raise ShapeError(f"inputs, target: need the same number (> 0) of samples, got {x.shape[0]} and {y.shape[0]}")
    if membership not in ("gaussian", "triangular"):
        raise ParameterError(f"membership: expected 'gaussian' or 'triangular', got {membership!r}")
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
    params = [_initial(c, membership) for c in counts]

    def loss(params):
        w = _forward(u, params, membership)[2]
        c = _consequents(w, y, ridge, bounds)
        return float(np.sqrt(np.mean((_predict(w, c) - y) ** 2))), c

    current, c = loss(params)
    history = [current]
    for _ in range(epochs):
        grads = _premise_gradient(u, params, membership, c, y)
        norm = np.sqrt(sum(float(np.sum(g ** 2)) for g in grads))
        if norm == 0.0:  # a stationary point: no premise step changes E to first order
            history.append(current)
            continue
        trial = [_valid(q - (eta / norm) * g, membership) for q, g in zip(params, grads)]
        if all(t is not None for t in trial):
            value, c_t = loss(trial)
            if value <= current:
                params, current, c = trial, value, c_t
                eta *= 1.1
                history.append(current)
                continue
        eta *= 0.5
        history.append(current)

    scale = hi - lo
    sets = []
    for j in range(p):
        if membership == "gaussian":
            sets.append(tuple(MembershipFunction("gaussian", (lo[j] + m * scale[j], s * scale[j]), f"A{j}{i}")
                              for i, (m, s) in enumerate(params[j])))
        else:
            sets.append(tuple(MembershipFunction("triangular", tuple(lo[j] + v * scale[j] for v in abc), f"A{j}{i}")
                              for i, abc in enumerate(params[j])))
    fis = TakagiSugeno(tuple(sets), c, universes=tuple((float(lo[j]), float(hi[j])) for j in range(p)),
                       names=names)
    return AnfisResult(fis=fis, rmse=np.array(history))
