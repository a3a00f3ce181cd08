"""Steady-state N-step prediction (seed 001 eqs. 15-20) and the inverse-free form."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.errors import ParameterError, ShapeError, SingularMatrixError
from mptrack.linear import (
    kalman_filter,
    predict_ahead,
    prediction_covariance,
    prediction_matrices,
    steady_state_filter,
    steady_state_predictor,
)
from mptrack.models import LinearGaussianModel, constant_acceleration, constant_velocity
from mptrack.riccati import steady_state
from mptrack.sim import simulate_linear

MODELS = {
    "cv": constant_velocity(1.0, 0.01, 1, sigma_r2=0.1),
    "ca": constant_acceleration(1.0, 0.01, 1, sigma_r2=0.1),
    "cv2d": constant_velocity(0.5, 0.2, 2, sigma_r2=1.0),
    "ca3d": constant_acceleration(0.2, 1.0, 3, sigma_r2=0.5),
}


def _data(model, T=80, seed=0):
    rng = np.random.default_rng(seed)
    return simulate_linear(model, T, rng, x0=rng.normal(size=model.n) * 5)


@pytest.mark.parametrize("name", list(MODELS))
@pytest.mark.parametrize("N", [1, 2, 3, 5, 8])
def test_recursive_equals_inverse_free(name, N):
    model = MODELS[name]
    _, z = _data(model)
    x0 = np.linspace(-1, 1, model.n)
    rec = steady_state_predictor(model, z, N, x0)
    free = steady_state_predictor(model, z, N, x0, method="inverse-free")
    scale = np.max(np.abs(free.x))
    np.testing.assert_allclose(rec.x, free.x, rtol=0, atol=1e-9 * scale)
    np.testing.assert_array_equal(rec.P, free.P)


@pytest.mark.parametrize("name", list(MODELS))
def test_ss_predictor_equals_kf_prediction_after_convergence(name):
    """x(k+N/k) of eq. 19 equals F^N x(k/k) of the time-varying KF once it has converged."""
    model = MODELS[name]
    _, z = _data(model, T=300)
    kf = kalman_filter(model, z, np.zeros(model.n), np.eye(model.n) * 100)
    for N in (1, 3):
        ss = steady_state_predictor(model, z, N, np.zeros(model.n))
        kf_pred = predict_ahead(model, kf, N)
        scale = np.max(np.abs(kf_pred.x))
        np.testing.assert_allclose(ss.x[-50:], kf_pred.x[-50:], rtol=0, atol=1e-8 * scale)
        np.testing.assert_allclose(ss.P[-1], kf_pred.P[-1], rtol=1e-8, atol=1e-12 * np.max(ss.P[-1]))


def test_matrices_follow_eqs_16_18_20():
    model = MODELS["ca"]
    ss = steady_state(model)
    F, K, H = model.F, ss.K, model.H
    I = np.eye(3)
    A1, B1 = prediction_matrices(model, 1)
    np.testing.assert_allclose(A1, F @ (I - K @ H), rtol=1e-13)          # eq. 16
    np.testing.assert_allclose(B1, F @ K, rtol=1e-13)
    A, Finv = ss.A, np.linalg.inv(F)
    for N in (2, 4):
        AN, BN = prediction_matrices(model, N, steady=ss)
        FN = np.linalg.matrix_power(F, N)
        # first form of eq. 20: F^N A F^-N with A = (I - KH) F (eq. 9)
        np.testing.assert_allclose(AN, FN @ A @ np.linalg.matrix_power(Finv, N), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(BN, FN @ K, rtol=1e-13)
        # A_N and A are similar: same eigenvalues, so the predictor is as stable as the filter
        np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(AN)), np.sort_complex(np.linalg.eigvals(A)),
                                   atol=1e-9)


def test_initial_condition_is_F_N_x0():
    model = MODELS["cv"]
    x0 = np.array([3.0, -2.0])
    z = np.array([[np.nan], [np.nan]])
    out = steady_state_predictor(model, z, 3, x0)
    F = model.F
    np.testing.assert_allclose(out.x[0], np.linalg.matrix_power(F, 4) @ x0)  # only predictions
    np.testing.assert_allclose(out.x[1], np.linalg.matrix_power(F, 5) @ x0)


def test_missing_measurements_agree_between_forms():
    model = MODELS["cv2d"]
    _, z = _data(model, T=50)
    z[[3, 10, 11, 30]] = np.nan
    a = steady_state_predictor(model, z, 4)
    b = steady_state_predictor(model, z, 4, method="inverse-free")
    np.testing.assert_allclose(a.x, b.x, atol=1e-9 * np.max(np.abs(b.x)))


def test_singular_F_needs_the_inverse_free_form():
    model = LinearGaussianModel([[1.0, 1.0], [0.0, 0.0]], [[1.0, 0.0]], np.eye(2), [[1.0]])
    z = np.random.default_rng(0).normal(size=(20, 1))
    steady_state_predictor(model, z, 1)  # N = 1 needs no inverse
    with pytest.raises(SingularMatrixError, match=r"model\.F: singular.*inverse-free"):
        steady_state_predictor(model, z, 2)
    with pytest.raises(SingularMatrixError, match="N = 3 >= 2"):
        prediction_matrices(model, 3)
    free = steady_state_predictor(model, z, 2, method="inverse-free")
    filt = steady_state_filter(model, z)
    np.testing.assert_allclose(free.x, filt.x @ np.linalg.matrix_power(model.F, 2).T)


def test_prediction_covariance_recursion():
    model = MODELS["cv"]
    Pe = steady_state(model).P_filt
    F, Q = model.F, model.Q
    expected = F @ F @ Pe @ F.T @ F.T + F @ Q @ F.T + Q
    np.testing.assert_allclose(prediction_covariance(model, Pe, 2), expected, rtol=1e-13)
    # one step is the steady prediction covariance Pp
    np.testing.assert_allclose(prediction_covariance(model, Pe, 1), steady_state(model).P_pred, rtol=1e-9)


def test_prediction_error_grows_with_N_monte_carlo():
    """Fixed seed: empirical MSE increases with N and matches P(k+N/k) within sampling error."""
    model = MODELS["cv"]
    rng = np.random.default_rng(2016)
    mse = np.zeros(6)
    runs, T, burn = 60, 200, 30
    ss = steady_state(model)
    for _ in range(runs):
        truth, z = simulate_linear(model, T + 5, rng)
        for N in range(6):
            pred = (steady_state_filter(model, z[:T], steady=ss) if N == 0
                    else steady_state_predictor(model, z[:T], N, steady=ss))
            err = pred.x[burn:, 0] - truth[burn + N:T + N, 0]
            mse[N] += np.mean(err**2) / runs
    assert np.all(np.diff(mse) > 0)
    Pe = steady_state(model).P_filt
    expect = [Pe[0, 0]] + [prediction_covariance(model, Pe, N)[0, 0] for N in range(1, 6)]
    np.testing.assert_allclose(mse, expect, rtol=0.15)


@settings(max_examples=25, deadline=None)
@given(dt=st.floats(0.05, 5.0), q=st.floats(1e-3, 10.0), r=st.floats(1e-3, 10.0), N=st.integers(1, 6))
def test_forms_agree_for_random_cv_models(dt, q, r, N):
    model = constant_velocity(dt, q, 1, sigma_r2=r)
    z = np.random.default_rng(0).normal(size=(30, 1)) * 10
    a = steady_state_predictor(model, z, N, [1.0, 1.0])
    b = steady_state_predictor(model, z, N, [1.0, 1.0], method="inverse-free")
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-8 * max(1.0, np.max(np.abs(b.x))))


@pytest.mark.parametrize("call,exc,match", [
    (lambda: steady_state_predictor(MODELS["cv"], np.zeros((5, 1)), 0), ParameterError, "N"),
    (lambda: steady_state_predictor(MODELS["cv"], np.zeros((5, 1)), -2), ParameterError, "N"),
    (lambda: steady_state_predictor(MODELS["cv"], np.zeros((5, 1)), 1.5), ParameterError, "N"),
    (lambda: prediction_matrices(MODELS["cv"], 0), ParameterError, "N"),
    (lambda: predict_ahead(MODELS["cv"], None, 1), ParameterError, "result"),
    (lambda: steady_state_predictor(MODELS["cv"], np.zeros((5, 2)), 1), ShapeError, "z"),
    (lambda: steady_state_predictor(MODELS["cv"], np.zeros((5, 1)), 1, method="magic"), ParameterError,
     "method"),
    (lambda: steady_state_predictor("cv", np.zeros((5, 1)), 1), ParameterError, "model"),
])
def test_bad_input(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


def test_predict_ahead_checks_dimensions():
    res = steady_state_filter(MODELS["cv"], np.zeros((4, 1)))
    with pytest.raises(ShapeError, match="result"):
        predict_ahead(MODELS["ca"], res, 1)


def test_the_steady_state_is_solved_once_per_model_and_shared_read_only():
    """Filters given no ``steady`` solve the model's steady state once (equal models built apart share
    it, as the batch and single-track filters do) and get it read-only; another model, or the other
    form, gets its own, equal to a fresh solve."""
    from mptrack import batch
    from mptrack._core.steady_input import steady_argument

    one, two = constant_velocity(1.0, 0.01, 1, sigma_r2=0.1), constant_velocity(1.0, 0.01, 1, sigma_r2=0.1)
    ss = steady_argument(one, None)
    assert steady_argument(two, None) is ss
    assert batch.steady_state_filter(two, np.zeros((2, 5, 1))).inputs["steady"] is ss
    assert not ss.K.flags.writeable and not ss.P_filt.flags.writeable and not ss.A.flags.writeable
    with pytest.raises(ValueError):
        ss.K[0, 0] = 1.0
    other = steady_argument(constant_velocity(1.0, 0.02, 1, sigma_r2=0.1), None)
    assert other is not ss and not np.allclose(other.K, ss.K)
    lainiotis = steady_argument(one, None, "lainiotis")
    assert lainiotis is not ss and lainiotis.form == "lainiotis"
    fresh = steady_state(one, "dare")
    for field in ("K", "P_pred", "P_filt", "A", "B"):
        np.testing.assert_array_equal(getattr(ss, field), getattr(fresh, field))
