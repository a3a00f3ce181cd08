"""Independent reference computations shared by several test files."""

import numpy as np


def batch_least_squares(Fs, Qs, H, R, z, x0, P0):
    """Smoothed means/covariances of x(1..T) by solving the whole-trajectory normal equations,
    with per-step transitions Fs[k-1], Qs[k-1] from x(k-1) to x(k): the reference smoother."""
    n, T = len(x0), z.shape[0]
    J = np.zeros(((T + 1) * n, (T + 1) * n))
    h = np.zeros((T + 1) * n)
    blk = lambda k: slice(k * n, (k + 1) * n)  # noqa: E731
    J[blk(0), blk(0)] += np.linalg.inv(P0)
    h[blk(0)] += np.linalg.solve(P0, x0)
    Ri = np.linalg.inv(R)
    for k in range(1, T + 1):
        F, Qi = Fs[k - 1], np.linalg.inv(Qs[k - 1])
        a, b = blk(k - 1), blk(k)
        J[a, a] += F.T @ Qi @ F
        J[a, b] -= F.T @ Qi
        J[b, a] -= Qi @ F
        J[b, b] += Qi + H.T @ Ri @ H
        h[b] += H.T @ Ri @ z[k - 1]
    cov = np.linalg.inv(J)
    return (cov @ h).reshape(T + 1, n)[1:], np.array([cov[blk(k), blk(k)] for k in range(1, T + 1)])
