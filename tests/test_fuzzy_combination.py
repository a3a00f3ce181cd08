"""Bouzera et al. (2017) section 3.3: Proposition 3 (eq. 29), Proposition 4 (eq. 30) and the
probabilistic combination rule (the second eq. 30)."""

import numpy as np
import pytest

from mptrack.cellular import fuse_local_solutions, local_solutions
from mptrack.errors import ParameterError
from mptrack.fuzzy import fused_covariance_prop3, fused_covariance_trace, probabilistic_fusion


def _scenario(seed=0):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(2, 2))
    P_pred = A @ A.T + 0.5 * np.eye(2)
    x_pred = rng.normal(size=2)
    stations = rng.uniform(-3, 3, size=(3, 2))
    R = np.array([0.1, 0.2, 0.3])
    z = np.linalg.norm(x_pred - stations, axis=1) + rng.normal(scale=0.1, size=3)
    y = rng.uniform(0.1, 1.0, size=3)
    _, K, H, innov, S = local_solutions(x_pred[None], P_pred[None], z[None], stations, R)
    P_local = np.eye(2)[None] @ P_pred - np.einsum("mn,mk->mnk", K[0], H[0]) @ P_pred
    return x_pred, P_pred, K, H, innov, S, R, y, P_local


def test_proposition_3_equals_eq_16():
    for seed in range(5):
        x_pred, P_pred, K, H, innov, S, R, y, P_local = _scenario(seed)
        _, P16 = fuse_local_solutions(x_pred[None], P_pred[None], K, H, innov, S, R, y[None], covariance="paper")
        P29 = fused_covariance_prop3(P_pred, P_local, H[0][:, None, :], S[0][:, None, None], y)
        np.testing.assert_allclose(0.5 * (P29 + P29.T), P16[0], atol=1e-12)


def test_proposition_4_trace_is_linear_with_slope_2w():
    x_pred, P_pred, K, H, innov, S, R, y, P_local = _scenario(1)
    args = (P_pred, P_local, H[0][:, None, :], S[0][:, None, None], y)
    base = fused_covariance_trace(*args)
    assert base == pytest.approx(np.trace(fused_covariance_prop3(*args)), abs=1e-12)
    w = y / y.sum()
    for i in range(3):
        bumped = P_local.copy()
        bumped[i] += 0.01 * np.eye(2)                      # trace(P_i) + 0.02
        new = fused_covariance_trace(P_pred, bumped, *args[2:])
        assert new - base == pytest.approx(2 * w[i] * 0.02, abs=1e-12)   # monotonic increasing


def test_probabilistic_fusion_is_inverse_variance_weighting():
    X = np.array([[1.0, 0.0], [3.0, 2.0]])
    P = np.array([np.diag([1.0, 4.0]), np.diag([3.0, 4.0])])
    x, Pf = probabilistic_fusion(X, P)
    np.testing.assert_allclose(x, [(1 / 1 + 3 / 3) / (1 / 1 + 1 / 3), 1.0])
    np.testing.assert_allclose(Pf, np.diag([0.75, 2.0]))
    # one source only: itself; identical sources: the same mean, covariance / N
    x1, P1 = probabilistic_fusion(X[:1], P[:1])
    np.testing.assert_allclose(x1, X[0])
    np.testing.assert_allclose(P1, P[0])
    x2, P2 = probabilistic_fusion(np.repeat(X[:1], 4, 0), np.repeat(P[:1], 4, 0))
    np.testing.assert_allclose(x2, X[0])
    np.testing.assert_allclose(P2, P[0] / 4)


def test_bad_input():
    with pytest.raises(ParameterError, match="y"):
        fused_covariance_trace(np.eye(2), np.eye(2)[None], np.ones((1, 1, 2)), np.ones((1, 1, 1)), [0.0])
    with pytest.raises(ParameterError, match="P"):
        probabilistic_fusion(np.zeros((2, 2)), np.zeros((2, 2, 2)))
    with pytest.raises(ParameterError, match="P"):
        probabilistic_fusion(np.zeros((2, 2)), np.zeros((2, 3, 3)))
