"""Fixed-interval RTS smoother and its steady-state version."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.errors import ParameterError, ShapeError
from mptrack.linear import (
    kalman_filter,
    lainiotis_filter,
    rts_smoother,
    steady_state_filter,
    steady_state_smoother,
)
from mptrack.models import constant_acceleration, constant_velocity, cv_discrete_white_noise
from mptrack.riccati import steady_state
from mptrack.sim import simulate_linear

from _oracles import batch_least_squares


def model_least_squares(model, z, x0, P0):
    """The batch least-squares smoother with the model's (F, Q) at every step."""
    T = z.shape[0]
    return batch_least_squares([model.F] * T, [model.Q] * T, model.H, model.R, z, x0, P0)


@pytest.mark.parametrize("model", [constant_velocity(1.0, 0.3, 1, sigma_r2=0.5),
                                   constant_acceleration(0.5, 0.2, 2, sigma_r2=1.0)])
def test_rts_equals_batch_least_squares(model):
    rng = np.random.default_rng(7)
    _, z = simulate_linear(model, 12, rng, x0=rng.normal(size=model.n))
    x0, P0 = rng.normal(size=model.n), 2.0 * np.eye(model.n)
    smooth = rts_smoother(model, kalman_filter(model, z, x0, P0))
    mean, cov = model_least_squares(model, z, x0, P0)
    np.testing.assert_allclose(smooth.x, mean, rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(smooth.P, cov, rtol=1e-8, atol=1e-10)
    assert smooth.method == "RTS"


def test_rts_on_lainiotis_result_equals_rts_on_kf():
    model = constant_velocity(1.0, 0.01, 2, sigma_r2=0.1)
    _, z = simulate_linear(model, 40, np.random.default_rng(1))
    a = rts_smoother(model, kalman_filter(model, z, None, np.eye(4)))
    b = rts_smoother(model, lainiotis_filter(model, z, None, np.eye(4)))
    np.testing.assert_allclose(a.x, b.x, rtol=1e-8, atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(dt=st.floats(0.1, 3.0), q=st.floats(1e-3, 5.0), r=st.floats(1e-2, 5.0), seed=st.integers(0, 10**6))
def test_smoothed_covariance_is_psd_and_below_filtered(dt, q, r, seed):
    model = constant_acceleration(dt, q, 1, sigma_r2=r)
    _, z = simulate_linear(model, 25, np.random.default_rng(seed))
    kf = kalman_filter(model, z, None, np.eye(3))
    sm = rts_smoother(model, kf)
    for Pf, Ps in zip(kf.P, sm.P):
        np.testing.assert_array_equal(Ps, Ps.T)
        scale = np.max(np.abs(Pf))
        assert np.linalg.eigvalsh(Ps)[0] >= -1e-10 * scale
        assert np.linalg.eigvalsh(Pf - Ps)[0] >= -1e-9 * scale
    np.testing.assert_array_equal(sm.x[-1], kf.x[-1])     # x(T/T) is already smoothed


def test_rank_deficient_noise_and_zero_prior_use_the_pseudo_inverse():
    model = cv_discrete_white_noise(1.0, 0.01, 1, sigma_r2=0.1)   # Q has rank 1; P(1/0) = Q singular
    _, z = simulate_linear(model, 30, np.random.default_rng(3))
    kf = kalman_filter(model, z, P0=np.zeros((2, 2)))            # P0 = 0
    sm = rts_smoother(model, kf)
    assert np.all(np.isfinite(sm.x)) and np.all(np.isfinite(sm.P))
    for Pf, Ps in zip(kf.P, sm.P):
        assert np.linalg.eigvalsh(Pf - Ps)[0] >= -1e-12


def test_steady_state_smoother_equals_rts_from_the_stationary_prior():
    """A KF started at P(0/0) = Pe stays at Pe, so its RTS gains are the steady ones."""
    model = constant_velocity(1.0, 0.01, 1, sigma_r2=0.1)
    ss = steady_state(model)
    _, z = simulate_linear(model, 200, np.random.default_rng(4))
    x0 = np.array([1.0, 0.5])
    rts = rts_smoother(model, kalman_filter(model, z, x0, ss.P_filt))
    sss = steady_state_smoother(model, steady_state_filter(model, z, x0, steady=ss), steady=ss)
    np.testing.assert_allclose(sss.x, rts.x, rtol=1e-9, atol=1e-9)
    # the RTS covariance recursion converges to the Lyapunov solution away from the end
    np.testing.assert_allclose(sss.P[0], rts.P[0], rtol=1e-9, atol=1e-14)
    assert sss.method == "SS-RTS"
    assert np.all(np.linalg.eigvalsh(ss.P_filt - sss.P[0]) > 0)


def test_smoother_beats_filter_in_monte_carlo():
    model = constant_velocity(1.0, 0.05, 1, sigma_r2=1.0)
    rng = np.random.default_rng(5)
    ss = steady_state(model)
    err_f = err_s = 0.0
    for _ in range(30):
        truth, z = simulate_linear(model, 100, rng)
        filt = steady_state_filter(model, z, steady=ss)
        sm = steady_state_smoother(model, filt, steady=ss)
        err_f += np.mean((filt.x[20:-20, 0] - truth[20:-20, 0]) ** 2)
        err_s += np.mean((sm.x[20:-20, 0] - truth[20:-20, 0]) ** 2)
    assert err_s < 0.8 * err_f
    np.testing.assert_allclose(err_s / 30, sm.P[0, 0, 0], rtol=0.2)


def test_bad_input():
    model = constant_velocity(1.0, 0.01, 1)
    res = kalman_filter(model, np.zeros((5, 1)), P0=np.eye(2))
    with pytest.raises(ShapeError, match="result"):
        rts_smoother(constant_velocity(1.0, 0.01, 2), res)
    with pytest.raises(ParameterError, match="result"):
        rts_smoother(model, res.x)
    with pytest.raises(ParameterError, match="model"):
        steady_state_smoother(None, res)


def test_rts_on_the_steady_state_filter_has_the_steady_gains():
    model = constant_acceleration(1.0, 0.01, 1, sigma_r2=0.1)
    ss = steady_state(model)
    _, z = simulate_linear(model, 60, np.random.default_rng(6))
    filt = steady_state_filter(model, z, steady=ss)
    np.testing.assert_allclose(rts_smoother(model, filt).x, steady_state_smoother(model, filt, steady=ss).x,
                               rtol=1e-10, atol=1e-10)
