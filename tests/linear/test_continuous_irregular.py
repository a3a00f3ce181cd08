"""Kalman filtering at irregular time stamps (the continuous model rediscretised per step)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.errors import MptrackError, ParameterError, ShapeError
from mptrack.linear import (
    kalman_filter,
    kalman_filter_irregular,
    kalman_step,
    rts_smoother,
    rts_smoother_irregular,
    sampling_intervals,
)
from mptrack.models import constant_acceleration_continuous, constant_velocity_continuous, discretize
from mptrack.sim import simulate_linear

from _oracles import batch_least_squares


@pytest.fixture
def cv2():
    return constant_velocity_continuous(0.05, 2, sigma_r2=0.2)


def test_equal_steps_equal_the_fixed_dt_filter(cv2):
    dt, T = 0.5, 60
    model = discretize(cv2, dt)
    _, z = simulate_linear(model, T, np.random.default_rng(0), x0=[0, 3, 0, -1])
    x0, P0 = np.array([0.1, 2.0, 0.0, -0.5]), np.eye(4)
    fixed = kalman_filter(model, z, x0, P0)
    irr = kalman_filter_irregular(cv2, dt * np.arange(1, T + 1), z, x0, P0)
    np.testing.assert_allclose(irr.x, fixed.x, rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(irr.P, fixed.P, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(irr.x_pred, fixed.x_pred, rtol=1e-11, atol=1e-11)
    assert irr.loglik == pytest.approx(fixed.loglik, rel=1e-11)
    assert irr.method == "KF-irregular"


def test_irregular_steps_match_a_per_step_reference():
    cont = constant_acceleration_continuous(0.2, 1, sigma_r2=0.5)
    rng = np.random.default_rng(1)
    dts = rng.uniform(0.05, 2.0, size=40)
    times = 10.0 + np.cumsum(dts)
    z = rng.normal(size=(40, 1)) + times[:, None]
    res = kalman_filter_irregular(cont, times, z, t0=10.0, P0=np.eye(3))
    x, P = np.zeros(3), np.eye(3)
    for k, dt in enumerate(dts):
        m = discretize(cont, dt)
        x, P, *_ = kalman_step(m.F, m.H, m.Q, m.R, x, P, z[k])
        np.testing.assert_allclose(res.x[k], x, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(res.P[k], P, rtol=1e-10, atol=1e-12)


def test_missing_stamp_equals_dropping_it(cv2):
    """Predicting through a NaN row over dt1 then dt2 = predicting once over dt1 + dt2."""
    times = np.array([0.3, 1.0, 1.4, 2.9, 3.0, 4.2])
    z = np.random.default_rng(2).normal(size=(6, 2))
    z_nan = z.copy()
    z_nan[2] = np.nan
    with_gap = kalman_filter_irregular(cv2, times, z_nan, P0=np.eye(4))
    dropped = kalman_filter_irregular(cv2, np.delete(times, 2), np.delete(z, 2, axis=0), P0=np.eye(4))
    np.testing.assert_allclose(np.delete(with_gap.x, 2, axis=0), dropped.x, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.delete(with_gap.P, 2, axis=0), dropped.P, rtol=1e-10, atol=1e-12)


def test_sampling_intervals():
    np.testing.assert_allclose(sampling_intervals([1.0, 1.5, 3.0], t0=0.5), [0.5, 0.5, 1.5])


@pytest.mark.parametrize("times,t0,match", [
    ([1.0, 1.0, 2.0], 0.0, r"times\[1\] = 1.0 is not after times\[0\]"),
    ([1.0, 0.5, 2.0], 0.0, r"times\[1\]"),
    ([0.0, 1.0], 0.0, r"times\[0\] = 0.0 is not after t0"),
    ([-1.0, 1.0], 0.0, "t0"),
    ([-1.7e308, 1.7e308], -1.8e300, r"times\[0\]"),
    ([1.7e308], -1.7e308, r"overflows"),
])
def test_non_increasing_time_stamps_are_rejected(cv2, times, t0, match):
    with pytest.raises(ParameterError, match=match):
        kalman_filter_irregular(cv2, times, np.zeros((len(times), 2)), t0=t0)


def test_bad_shapes_and_model(cv2):
    with pytest.raises(ShapeError, match="z"):
        kalman_filter_irregular(cv2, [1.0, 2.0, 3.0], np.zeros((2, 2)))
    with pytest.raises(ShapeError, match="times"):
        kalman_filter_irregular(cv2, [[1.0, 2.0]], np.zeros((2, 2)))
    with pytest.raises(ParameterError, match="model"):
        kalman_filter_irregular(discretize(cv2, 1.0), [1.0], np.zeros((1, 2)))


def test_irregular_smoother_equals_batch_least_squares():
    cont = constant_acceleration_continuous(0.5, 1, sigma_r2=0.3)
    rng = np.random.default_rng(5)
    dts = rng.uniform(0.1, 1.5, size=10)
    times = np.cumsum(dts)
    z = rng.normal(size=(10, 1)) + times[:, None] ** 2
    x0, P0 = np.array([0.0, 1.0, 0.5]), np.eye(3)
    res = kalman_filter_irregular(cont, times, z, x0, P0)
    sm = rts_smoother_irregular(cont, times, res)
    models = [discretize(cont, dt) for dt in dts]
    mean, cov = batch_least_squares([m.F for m in models], [m.Q for m in models], cont.H, cont.R, z, x0, P0)
    np.testing.assert_allclose(sm.x, mean, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(sm.P, cov, rtol=1e-7, atol=1e-10)


def test_irregular_smoother_with_equal_stamps_is_rts(cv2):
    model = discretize(cv2, 0.5)
    _, z = simulate_linear(model, 30, np.random.default_rng(6))
    times = 0.5 * np.arange(1, 31)
    kf = kalman_filter(model, z, None, np.eye(4))
    np.testing.assert_allclose(rts_smoother_irregular(cv2, times, kf).x, rts_smoother(model, kf).x,
                               rtol=1e-10, atol=1e-10)
    one = kalman_filter_irregular(cv2, [2.0], z[:1])
    np.testing.assert_array_equal(rts_smoother_irregular(cv2, [2.0], one).x, one.x)
    with pytest.raises(ShapeError, match="result"):
        rts_smoother_irregular(cv2, times[:-1], kf)


@settings(max_examples=80, deadline=None)
@given(times=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=0, max_size=8),
       t0=st.floats(-10, 10))
def test_time_stamp_validation_never_crashes(times, t0):
    """Any list of numbers: either strictly increasing positive intervals or a clear mptrack error."""
    try:
        dts = sampling_intervals(times, t0)
    except MptrackError as err:
        assert "times" in str(err)
    else:
        assert dts.shape == (len(times),) and np.all(dts > 0)
