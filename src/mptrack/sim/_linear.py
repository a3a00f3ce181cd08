"""Sampling a linear-Gaussian model."""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result
from .._core.validation import as_vector, check_allocation, check_int, check_rng
from ..models import LinearGaussianModel, require_model

__all__ = ["simulate_linear"]


@finite_result("the simulation")
def simulate_linear(model: LinearGaussianModel, steps: int, rng: np.random.Generator,
                    x0=None) -> tuple[np.ndarray, np.ndarray]:
    """Sample a linear-Gaussian model: x(k+1) = F x(k) + w(k), z(k) = H x(k) + v(k), k = 1..steps.

    Row k-1 holds time k, the filters' convention (the prior is x(0/0), z[0] = z(1)).

    Parameters
    ----------
    model : LinearGaussianModel
        The model (F, H, Q, R).
    steps : int
        Number of steps, >= 1.
    rng : numpy.random.Generator
        The random generator (the process noise is drawn first, then the measurement noise).
    x0 : array_like, shape (n,), optional
        The initial state x(0) (default 0).

    Returns
    -------
    truth : ndarray, shape (steps, n)
    z : ndarray, shape (steps, m)

    Raises
    ------
    ResourceError
        The samples would exceed the memory limit.
    """
    require_model(model)
    check_rng(rng)
    steps = check_int("steps", steps, minimum=1)
    check_allocation("steps", steps, 8.0 * steps * (2 * model.n + 2 * model.m))
    x = np.zeros(model.n) if x0 is None else as_vector("x0", x0, model.n)
    Lq = model.noise_factor()
    Lr = np.linalg.cholesky(model.R)
    w = rng.standard_normal((steps, Lq.shape[1])) @ Lq.T
    v = rng.standard_normal((steps, model.m)) @ Lr.T
    truth = np.empty((steps, model.n))
    for k in range(steps):
        x = model.F @ x + w[k]
        truth[k] = x
    return truth, truth @ model.H.T + v
