"""Continuous CV/CA models: Van Loan discretisation against the closed forms of seed 001."""

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.errors import NotPositiveDefiniteError, ParameterError, ShapeError
from mptrack.models import (
    ContinuousLinearModel,
    assimakis_model_b,
    ca_discrete_white_noise,
    constant_acceleration,
    constant_acceleration_continuous,
    constant_velocity,
    constant_velocity_continuous,
    cv_discrete_white_noise,
    discretize,
    van_loan,
)

dts = st.floats(min_value=1e-3, max_value=50.0)
qs = st.floats(min_value=1e-4, max_value=10.0)


def cv_closed(dt, q):
    """Seed 001 eq. 5."""
    return (np.array([[1, dt], [0, 1.0]]),
            q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))


def ca_closed(dt, q):
    """Seed 001 eq. 6 as printed in sec. 5.2 ((1,3) entry dt^3/6, see the errata)."""
    return (np.array([[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1.0]]),
            q * np.array([[dt**5 / 20, dt**4 / 8, dt**3 / 6],
                          [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                          [dt**3 / 6, dt**2 / 2, dt]]))


def close(a, b, rtol=1e-12):
    return np.max(np.abs(a - b)) <= rtol * max(np.max(np.abs(b)), 1e-300)


@settings(max_examples=60, deadline=None)
@given(dt=dts, q=qs)
def test_cv_van_loan_equals_closed_form(dt, q):
    F, Q = cv_closed(dt, q)
    m = constant_velocity(dt, q, sigma_r2=0.1)
    assert close(m.F, F) and close(m.Q, Q)
    assert np.array_equal(m.H, [[1.0, 0.0]]) and m.R[0, 0] == 0.1 and m.dt == dt


@settings(max_examples=60, deadline=None)
@given(dt=dts, q=qs)
def test_ca_van_loan_equals_closed_form(dt, q):
    F, Q = ca_closed(dt, q)
    m = constant_acceleration(dt, q)
    assert close(m.F, F) and close(m.Q, Q)


def test_paper_example_values_pinned():
    """Section 5: dt = 1, sigma_q^2 = 0.01."""
    cv = constant_velocity(1.0, 0.01, sigma_r2=0.1)
    np.testing.assert_allclose(cv.Q, [[0.01 / 3, 0.005], [0.005, 0.01]], rtol=1e-14)
    ca = constant_acceleration(1.0, 0.01, sigma_r2=0.1)
    assert ca.Q[0, 2] == pytest.approx(0.01 / 6, rel=1e-14)   # not the 1/3 printed in sec. 2.2
    assert ca.Q[2, 0] == pytest.approx(0.01 / 6, rel=1e-14)
    assert ca.Q[0, 0] == pytest.approx(0.01 / 20, rel=1e-14)


@pytest.mark.parametrize("make,order", [(constant_velocity, 2), (constant_acceleration, 3)])
@pytest.mark.parametrize("axes", [1, 2, 3])
def test_axes_are_block_diagonal_and_measure_positions(make, order, axes):
    one = make(0.7, 0.2, 1, sigma_r2=0.3)
    m = make(0.7, 0.2, axes, sigma_r2=0.3)
    assert m.n == order * axes and m.m == axes
    np.testing.assert_allclose(m.F, scipy.linalg.block_diag(*[one.F] * axes), atol=1e-15)
    np.testing.assert_allclose(m.Q, scipy.linalg.block_diag(*[one.Q] * axes), rtol=1e-13, atol=1e-16)
    np.testing.assert_array_equal(m.R, 0.3 * np.eye(axes))
    for a in range(axes):
        row = np.zeros(order * axes)
        row[a * order] = 1.0
        np.testing.assert_array_equal(m.H[a], row)


def test_van_loan_matches_numerical_integral_for_a_general_model():
    rng = np.random.default_rng(3)
    Phi = rng.normal(size=(3, 3)) - np.eye(3)
    L = rng.normal(size=(3, 2))
    Qc = np.array([[2.0, 0.3], [0.3, 0.5]])
    dt = 0.8
    F, Q = van_loan(Phi, L, Qc, dt)
    np.testing.assert_allclose(F, scipy.linalg.expm(Phi * dt), rtol=1e-12)
    integrand = lambda s: scipy.linalg.expm(Phi * s) @ L @ Qc @ L.T @ scipy.linalg.expm(Phi.T * s)  # noqa: E731
    Q_num, _ = scipy.integrate.quad_vec(integrand, 0.0, dt, epsabs=1e-14, epsrel=1e-13)
    np.testing.assert_allclose(Q, Q_num, rtol=1e-10, atol=1e-13)
    np.testing.assert_array_equal(Q, Q.T)


@settings(max_examples=40, deadline=None)
@given(dt1=st.floats(0.01, 5.0), dt2=st.floats(0.01, 5.0))
def test_discretisation_is_a_semigroup(dt1, dt2):
    """Sampling over dt1 then dt2 equals sampling over dt1 + dt2 (exactness of the discretisation)."""
    model = constant_acceleration_continuous(0.3, 2, sigma_r2=1.0)
    a, b, ab = discretize(model, dt1), discretize(model, dt2), discretize(model, dt1 + dt2)
    np.testing.assert_allclose(b.F @ a.F, ab.F, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(b.F @ a.Q @ b.F.T + b.Q, ab.Q, rtol=1e-10, atol=1e-13)


def test_zero_dt_van_loan_is_identity():
    F, Q = van_loan([[0, 1], [0, 0]], [[0], [1]], [[1.0]], 0.0)
    np.testing.assert_array_equal(F, np.eye(2))
    np.testing.assert_array_equal(Q, np.zeros((2, 2)))


def test_discrete_white_noise_variants():
    dt, q = 0.5, 0.2
    cv = cv_discrete_white_noise(dt, q, sigma_r2=0.1)
    G = np.array([[dt**2 / 2], [dt]])
    np.testing.assert_allclose(cv.Q, q * G @ G.T, rtol=1e-15)
    assert np.linalg.matrix_rank(cv.Q) == 1
    assert "discrete white noise" in cv.name
    ca = ca_discrete_white_noise(dt, q, 3)
    G = np.array([[dt**2 / 2], [dt], [1.0]])
    np.testing.assert_allclose(ca.Q[:3, :3], q * G @ G.T, rtol=1e-15)
    assert ca.n == 9 and ca.m == 3
    # continuous and discrete noise models are different models
    assert not np.allclose(constant_velocity(dt, q).Q, cv.Q)


def test_cv_discrete_white_noise_is_seed_000_model_b_at_unit_dt():
    ours = cv_discrete_white_noise(1.0, 0.01, sigma_r2=0.1)
    paper = assimakis_model_b(1.0, 0.01, 0.1, measurement="position")
    np.testing.assert_allclose(ours.Q, paper.Q, rtol=1e-15)
    np.testing.assert_array_equal(ours.F, paper.F)
    np.testing.assert_array_equal(ours.H, paper.H)


def test_continuous_model_is_frozen_and_discretizes():
    m = constant_velocity_continuous(0.1, 2, sigma_r2=0.5)
    assert isinstance(m, ContinuousLinearModel) and m.n == 4 and m.m == 2
    with pytest.raises(ValueError):
        m.Phi[0, 0] = 1.0
    np.testing.assert_allclose(m.discretize(2.0).Q, constant_velocity(2.0, 0.1, 2, sigma_r2=0.5).Q)


@pytest.mark.parametrize("call,exc,name", [
    (lambda: constant_velocity(-1.0, 0.1), ParameterError, "dt"),
    (lambda: constant_velocity(0.0, 0.1), ParameterError, "dt"),
    (lambda: constant_acceleration(float("nan"), 0.1), ParameterError, "dt"),
    (lambda: constant_velocity(1.0, -0.1), ParameterError, "q"),
    (lambda: constant_velocity(1.0, 0.1, 4), ParameterError, "axes"),
    (lambda: constant_acceleration(1.0, 0.1, 0), ParameterError, "axes"),
    (lambda: constant_velocity(1.0, 0.1, sigma_r2=0.0), ParameterError, "sigma_r2"),
    (lambda: cv_discrete_white_noise(-0.5, 0.1), ParameterError, "dt"),
    (lambda: constant_velocity(1e120, 1.0), ParameterError, "dt: 1e.120 s is too long"),
    (lambda: van_loan([[50.0]], [[1.0]], [[1.0]], 100.0), ParameterError, "overflows"),
    (lambda: van_loan([[0, 1]], [[0], [1]], [[1.0]], 1.0), ShapeError, "Phi"),
    (lambda: van_loan([[0, 1], [0, 0]], [[0], [1]], [[-1.0]], 1.0), NotPositiveDefiniteError, "Qc"),
    (lambda: van_loan([[0, 1], [0, 0]], [[0], [1]], [[1.0]], -0.1), ParameterError, "dt"),
    (lambda: discretize(constant_velocity(1.0, 0.1), 1.0), ParameterError, "model"),
    (lambda: ContinuousLinearModel(np.zeros((2, 2)), [[0], [1]], [[1.0]], [[1, 0, 0]], [[1.0]]),
     ShapeError, "H"),
])
def test_bad_input_names_the_argument(call, exc, name):
    with pytest.raises(exc, match=name):
        call()
