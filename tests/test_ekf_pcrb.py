"""PCRB: Tichavský recursion == covariance form == Kalman covariance on a linear model; bounds EKF RMSE."""

import numpy as np
import pytest

from mptrack.cellular import ekf_ranges_batch
from mptrack.errors import ShapeError, SingularMatrixError
from mptrack.linear import kalman_filter
from mptrack.metrics import nees, pcrb, pcrb_ranges, pcrb_tichavsky, position_error, range_fisher_information, rmse
from mptrack.models import LinearGaussianModel

STATIONS = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1.7]])


def test_pcrb_equals_kalman_covariance_for_linear_gaussian_model():
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    H = np.array([[1.0, 0.0]])
    Q = np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]]) * 0.1
    R = np.array([[0.5]])
    P0 = np.eye(2)
    model = LinearGaussianModel(F, H, Q, R)
    kf = kalman_filter(model, np.zeros((25, 1)), np.zeros(2), P0)
    info = np.broadcast_to(H.T @ np.linalg.inv(R) @ H, (25, 2, 2))
    np.testing.assert_allclose(pcrb(F, Q, P0, info), kf.P, rtol=1e-10)
    np.testing.assert_allclose(pcrb_tichavsky(F, Q, P0, info), kf.P, rtol=1e-8)


def test_range_information_and_bound_shapes():
    t = np.arange(1, 31)
    truth = np.stack([0.3 + 0.01 * t, 0.4 + 0.005 * t], 1)
    info = range_fisher_information(truth, STATIONS, 1e-2, n=4)
    assert info.shape == (30, 4, 4) and np.all(info[:, 2:, :] == 0)
    np.testing.assert_allclose(np.trace(info[:, :2, :2], axis1=1, axis2=2), 3 / 1e-2)  # unit vectors
    b = pcrb_ranges(truth, STATIONS, 1e-3 * np.eye(2), 1e-3 * np.eye(2), 1e-2)
    assert b.shape == (30,) and np.all(np.diff(b[5:]) < 1e-3)
    with pytest.raises(SingularMatrixError):
        range_fisher_information(STATIONS[:1], STATIONS, 1.0)
    with pytest.raises(ShapeError):
        range_fisher_information(np.zeros((3, 3)), STATIONS, 1.0)


def test_matched_ekf_rmse_is_near_and_above_the_bound():
    # random-walk truth matching the filter's model: the EKF RMSE must be >= PCRB and close to it
    rng = np.random.default_rng(5)
    B, T = 300, 40
    Q = 1e-4 * np.eye(2)
    r = 1e-3
    P0 = 1e-3 * np.eye(2)
    x0 = np.array([0.8, 0.6])
    truth = x0 + rng.multivariate_normal(np.zeros(2), P0, B)[:, None] + np.cumsum(
        rng.multivariate_normal(np.zeros(2), Q, (B, T)), axis=1)
    z = np.linalg.norm(truth[:, :, None, :] - STATIONS, axis=-1) + np.sqrt(r) * rng.standard_normal((B, T, 3))
    res = ekf_ranges_batch(z, STATIONS, np.broadcast_to(x0, (B, 2)), P0, Q, r)
    ours = rmse(res.x, truth)
    bound = pcrb_ranges(truth, STATIONS, P0, Q, r)
    assert np.all(ours[5:] > 0.85 * bound[5:])   # >= up to Monte-Carlo error
    assert np.mean(ours / bound) < 1.15
    assert position_error(res.x, truth).shape == (B, T)
    # consistency: average NEES over the runs inside the two-sided 99 % chi-square band (n = 2, B runs)
    from scipy.stats import chi2

    avg = nees(res.x, res.P, truth).mean(axis=0)
    lo, hi = chi2.ppf([0.005, 0.995], 2 * B) / B
    assert np.mean((avg > lo) & (avg < hi)) > 0.9


def test_pcrb_with_zero_process_noise_accumulates_information():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((10, 2, 2))
    info = A @ A.transpose(0, 2, 1)
    P0 = np.diag([0.5, 2.0])
    bound = pcrb(np.eye(2), np.zeros((2, 2)), P0, info)
    expect = np.linalg.inv(np.linalg.inv(P0) + np.cumsum(info, axis=0))
    np.testing.assert_allclose(bound, expect, rtol=1e-10)
