"""The continuous-discrete UKF: ≡ KF on a linear model, angle handling, bad input."""

from dataclasses import replace

import numpy as np
import pytest

from mptrack.continuous import linear_sde_model, simulate_sde, zhao2013_model
from mptrack.errors import NotPositiveDefiniteError, ParameterError
from mptrack.linear import kalman_filter
from mptrack.nonlinear import sigma_points, ukf_filter


def test_ukf_equals_kalman_on_linear_model():
    A = np.array([[0.0, 1.0], [-2.0, -0.3]])
    model = linear_sde_model(A, np.diag([0.2, 0.5]), [[1.0, 0.5]], [[0.3]], 0.5, substeps=40)
    _, z = simulate_sde(model, 25, np.random.default_rng(3), [1.0, -1.0])
    kf = kalman_filter(model.to_linear_gaussian(), z, [0.5, 0.0], np.eye(2))
    uk = ukf_filter(model, z, [0.5, 0.0], np.eye(2), substeps=model.substeps)   # 40 RK4 sub-steps
    np.testing.assert_allclose(uk.x, kf.x, atol=1e-7)
    np.testing.assert_allclose(uk.P, kf.P, atol=1e-7)
    assert uk.loglik == pytest.approx(kf.loglik, abs=1e-6)
    assert uk.method == "UKF"


def test_default_substeps_follow_the_drift_rate():
    """By default the sub-steps keep h * rho <= 0.25 (rho: |df/dx| row sums at the sigma points): on the
    linear model, 5 sub-steps per dt = 0.5 (rho = 2.3) and the RK4 error stays below 1e-4 of the KF; a
    drift ten times faster takes ten times the sub-steps."""
    from mptrack.continuous._ukf import drift_substeps

    A = np.array([[0.0, 1.0], [-2.0, -0.3]])
    model = linear_sde_model(A, np.diag([0.2, 0.5]), [[1.0, 0.5]], [[0.3]], 0.5)
    ut = {"alpha": 1.0, "beta": 2.0, "kappa": 0.0}
    assert drift_substeps(model, np.zeros(2), np.eye(2), ut) == 5
    fast = linear_sde_model(10 * A, np.diag([0.2, 0.5]), [[1.0, 0.5]], [[0.3]], 0.5)
    assert drift_substeps(fast, np.zeros(2), np.eye(2), ut) == 47
    _, z = simulate_sde(model, 25, np.random.default_rng(3), [1.0, -1.0])
    kf = kalman_filter(model.to_linear_gaussian(), z, [0.5, 0.0], np.eye(2))
    uk = ukf_filter(model, z, [0.5, 0.0], np.eye(2))
    np.testing.assert_allclose(uk.x, kf.x, atol=1e-4)
    assert np.abs(uk.x - kf.x).max() > 1e-9     # not the exact KF: the integration is coarser


def test_compiled_continuous_discrete_ukf_equals_the_numpy_path():
    """The compiled UKF (models with kernels) has the NumPy path's arithmetic: same sub-steps, estimates to
    rounding, with a bearing across ±pi and a missing component; 20 runs of eq. 42 at Q x 1, where 20
    fixed sub-steps lose the covariance's positive definiteness in 11, all run."""
    model = zhao2013_model(variant="vdp", diffusion_scale=1.0)
    x0, P0 = np.array([-0.6, -1.0]), 0.1 * np.eye(2)
    for seed in range(20):
        _, z = simulate_sde(model, 30, np.random.default_rng(100 + seed), x0)
        if seed == 0:
            z[4, 1] = np.nan
        fast = ukf_filter(model, z, x0, P0)
        slow = ukf_filter(model, z, x0, P0, compiled=False)
        np.testing.assert_allclose(fast.x, slow.x, rtol=0, atol=1e-10)
        np.testing.assert_allclose(fast.P, slow.P, rtol=0, atol=1e-10)
        np.testing.assert_allclose(fast.P_pred, slow.P_pred, rtol=0, atol=1e-10)
        assert fast.loglik == pytest.approx(slow.loglik, abs=1e-8)
    with pytest.raises(ParameterError, match="compiled"):
        ukf_filter(replace(model, kernels=None), z, x0, P0, compiled=True)


def test_sigma_points_reproduce_mean_and_covariance():
    m, P = np.array([1.0, -2.0]), np.array([[2.0, 0.3], [0.3, 0.5]])
    for alpha, kappa in ((1.0, 0.0), (0.5, 1.0), (1e-3, 0.0)):
        X, Wm, Wc = sigma_points(m, P, alpha=alpha, kappa=kappa)
        np.testing.assert_allclose(Wm @ X, m)
        np.testing.assert_allclose((Wc[:, None] * (X - m)).T @ (X - m), P, atol=1e-9)


def test_bearing_innovation_is_wrapped():
    model = zhao2013_model()
    # truth just across the ±π branch cut from the estimate: the innovation is small
    nu = model.innovation([1.0, np.pi - 0.01], [1.0, -np.pi + 0.01])
    assert nu[1] == pytest.approx(-0.02)
    printed = zhao2013_model(bearing="atan")
    np.testing.assert_allclose(printed.measurement(np.array([[1.0, 1.0], [-1.0, -1.0]]))[:, 1], np.pi / 4)
    assert zhao2013_model().measurement(np.array([-1.0, -1.0]))[1] == pytest.approx(-3 * np.pi / 4)


def test_ukf_tracks_across_the_branch_cut():
    """A state crossing bearing ±π (x2 < 0, x1 changing sign) is tracked without a jump."""
    model = zhao2013_model(variant="vdp", diffusion_scale=0.001)
    truth = np.stack([np.linspace(-0.5, 0.5, 11), -np.ones(11)], axis=1)
    z = model.measurement(truth)
    res = ukf_filter(model, z, truth[0], 0.01 * np.eye(2))
    assert np.abs(res.x[:, 0] - model.flow(truth[0])[0]).max() < 5  # finite, no branch-cut blow-up
    assert np.all(np.isfinite(res.x))


def test_ukf_nan_row_only_predicts():
    model = zhao2013_model(variant="vdp", diffusion_scale=0.1)
    z = np.array([[1.0, 0.1], [np.nan, np.nan], [1.1, np.nan]])
    res = ukf_filter(model, z, [-0.6, -1.0], 0.1 * np.eye(2))
    np.testing.assert_allclose(res.x[1], res.x_pred[1])
    assert not np.allclose(res.x[2], res.x_pred[2])


def test_ukf_bad_input():
    model = zhao2013_model()
    with pytest.raises(NotPositiveDefiniteError, match="P0"):
        ukf_filter(model, np.zeros((2, 2)), [0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(ParameterError, match="model"):
        ukf_filter("not a model", np.zeros((2, 2)), [0.0, 0.0], np.eye(2))
    with pytest.raises(NotPositiveDefiniteError, match="Q"):
        linear_sde_model(np.eye(2), np.diag([1.0, -0.5]), np.eye(2), np.eye(2), 1.0)
    with pytest.raises(NotPositiveDefiniteError, match="R"):
        linear_sde_model(np.eye(2), np.eye(2), np.eye(2), np.diag([1.0, -1.0]), 1.0)
    with pytest.raises(ParameterError, match="variant"):
        zhao2013_model(variant="reversed")
    with pytest.raises(ParameterError, match="diffusion_scale"):
        zhao2013_model(diffusion_scale=-1.0)
