"""The linear-Gaussian model record and the papers' models A and B (seed 000 eqs. 1-3, seed 002)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg

from mptrack.models import LinearGaussianModel, assimakis_model_a, assimakis_model_b, stack_axes
from mptrack.sim import simulate_linear


# --------------------------------------------------------------------------- model B (eq. 3)

@pytest.mark.parametrize("dt", [1.0, 0.5, 2.0])
def test_model_b_matrices_as_printed(dt):
    m = assimakis_model_b(dt=dt, sigma_q2=0.01, sigma_r2=0.1)
    np.testing.assert_array_equal(m.F, [[1.0, dt], [0.0, 1.0]])
    np.testing.assert_array_equal(m.G, [[dt / 2], [1.0]])
    np.testing.assert_array_equal(m.H, [[1.0, dt]])  # H = [1 dt] as printed
    np.testing.assert_array_equal(m.Qw, [[0.01]])
    np.testing.assert_array_equal(m.R, [[0.1]])
    # Q = sigma_q^2 G G^T, written out
    np.testing.assert_allclose(m.Q, 0.01 * np.array([[dt * dt / 4, dt / 2], [dt / 2, 1.0]]), rtol=1e-15)
    assert (m.n, m.m, m.dt) == (2, 1, dt)


def test_model_b_defaults_are_the_papers_example():
    """Example 1 of seed 000: dt = 1, sigma_q^2 = 0.01, sigma_r^2 = 0.1."""
    m = assimakis_model_b()
    np.testing.assert_array_equal(m.Q, [[0.0025, 0.005], [0.005, 0.01]])
    np.testing.assert_array_equal(m.R, [[0.1]])
    np.testing.assert_array_equal(m.H, [[1.0, 1.0]])


def test_model_b_textbook_measurement():
    m = assimakis_model_b(dt=0.5, measurement="position")
    np.testing.assert_array_equal(m.H, [[1.0, 0.0]])
    np.testing.assert_array_equal(m.F, [[1.0, 0.5], [0.0, 1.0]])


# --------------------------------------------------------------------------- model A (eq. 2; seed 002)

def test_model_a_2d_matrices_as_printed():
    dt = 0.5
    m = assimakis_model_a(2, dt=dt, sigma_q2=0.03, sigma_r2=0.2)
    np.testing.assert_array_equal(m.F, [[1, dt, 0, 0], [0, 1, 0, 0], [0, 0, 1, dt], [0, 0, 0, 1]])
    np.testing.assert_array_equal(m.G, [[dt / 2, 0], [1, 0], [0, dt / 2], [0, 1]])
    np.testing.assert_array_equal(m.H, [[1, dt, 0, 0], [0, 0, 1, dt]])
    np.testing.assert_array_equal(m.Qw, np.diag([0.03, 0.03]))
    np.testing.assert_array_equal(m.R, np.diag([0.2, 0.2]))
    assert (m.n, m.m) == (4, 2)


def test_model_a_3d_is_block_diagonal_in_axis_order():
    m = assimakis_model_a(3)
    b = assimakis_model_b()
    assert (m.n, m.m) == (6, 3)
    for M_a, M_b in ((m.F, b.F), (m.H, b.H), (m.Q, b.Q), (m.R, b.R), (m.G, b.G), (m.Qw, b.Qw)):
        np.testing.assert_array_equal(M_a, scipy.linalg.block_diag(M_b, M_b, M_b))


@pytest.mark.parametrize("measurement", ["printed", "position"])
@pytest.mark.parametrize("axes", [2, 3])
def test_stack_axes_of_model_b_is_model_a(axes, measurement):
    a = assimakis_model_a(axes, dt=0.7, sigma_q2=0.02, sigma_r2=0.3, measurement=measurement)
    s = stack_axes(assimakis_model_b(0.7, 0.02, 0.3, measurement), axes)
    for name in ("F", "H", "Q", "R", "G", "Qw"):
        np.testing.assert_array_equal(getattr(s, name), getattr(a, name), err_msg=name)
    assert s.dt == a.dt == 0.7


def test_stack_axes_without_noise_gain():
    axis = LinearGaussianModel([[0.9]], [[2.0]], [[0.3]], [[0.5]])
    s = stack_axes(axis, 3)
    np.testing.assert_array_equal(s.Q, 0.3 * np.eye(3))
    np.testing.assert_array_equal(s.H, 2.0 * np.eye(3))
    assert s.G is None and s.Qw is None


# --------------------------------------------------------------------------- the record itself

def _small_model(**kw):
    return LinearGaussianModel([[1.0, 1.0], [0.0, 1.0]], [[1.0, 0.0]], np.eye(2) * 0.1, [[0.5]], **kw)


def test_model_is_frozen_and_arrays_read_only():
    m = _small_model()
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.F = np.eye(2)
    for name in ("F", "H", "Q", "R"):
        arr = getattr(m, name)
        assert not arr.flags.writeable, name
        with pytest.raises(ValueError):
            arr[0, 0] = 42.0


def test_model_copies_its_inputs():
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    Q = np.eye(2)
    m = LinearGaussianModel(F, [[1.0, 0.0]], Q, [[1.0]])
    F[0, 0] = 99.0
    Q[1, 1] = 99.0
    assert m.F[0, 0] == 1.0 and m.Q[1, 1] == 1.0
    assert m.F.dtype == np.float64


def test_integer_and_scalar_inputs_are_promoted():
    m = LinearGaussianModel([[1, 1], [0, 1]], [[1, 0]], [[1, 0], [0, 1]], 2)
    assert m.F.dtype == np.float64
    np.testing.assert_array_equal(m.R, [[2.0]])
    scalar = LinearGaussianModel(0.5, 1, 0.2, 0.1)
    assert (scalar.n, scalar.m) == (1, 1)


def test_slightly_asymmetric_covariance_is_symmetrised():
    Q = np.array([[1.0, 0.5], [0.5 + 1e-13, 1.0]])
    m = LinearGaussianModel(np.eye(2) * 0.5, [[1.0, 0.0]], Q, [[1.0]])
    np.testing.assert_array_equal(m.Q, m.Q.T)


def test_from_noise_gain_forms_q():
    G = np.array([[0.5, 0.1], [1.0, 0.0], [0.2, 2.0]])
    Qw = np.array([[0.3, 0.1], [0.1, 0.2]])
    m = LinearGaussianModel.from_noise_gain(np.eye(3) * 0.9, np.ones((1, 3)), G, Qw, [[1.0]], dt=0.1,
                                            name="gain")
    np.testing.assert_allclose(m.Q, G @ Qw @ G.T, rtol=1e-15)
    np.testing.assert_array_equal(m.Q, m.Q.T)
    assert m.name == "gain" and m.dt == 0.1
    # Q together with a consistent (G, Qw) is accepted
    same = LinearGaussianModel(np.eye(3) * 0.9, np.ones((1, 3)), G @ Qw @ G.T, [[1.0]], G=G, Qw=Qw)
    np.testing.assert_allclose(same.Q, m.Q, rtol=1e-15)


def test_singular_q_is_accepted():
    """The papers' Q = sigma^2 G G^T has rank 1: PSD, not PD, must be allowed."""
    m = assimakis_model_b()
    assert np.linalg.matrix_rank(m.Q) == 1


@pytest.mark.parametrize("use_gain", [True, False])
def test_noise_factor_squares_to_q(use_gain):
    G = np.array([[0.5], [1.0], [0.3]])
    if use_gain:
        m = LinearGaussianModel.from_noise_gain(np.eye(3), np.eye(3), G, [[0.04]], np.eye(3))
    else:
        m = LinearGaussianModel(np.eye(3), np.eye(3), 0.04 * G @ G.T + np.diag([0, 0.1, 0]), np.eye(3))
    L = m.noise_factor()
    np.testing.assert_allclose(L @ L.T, m.Q, rtol=1e-12, atol=1e-16)


def test_repr_names_the_model():
    text = repr(assimakis_model_a(3))
    assert "n=6" in text and "m=3" in text and "3-D" in text


# --------------------------------------------------------------------------- simulator

def test_simulate_shapes_and_determinism():
    m = assimakis_model_a(2)
    t1, z1 = simulate_linear(m, 50, np.random.default_rng(5))
    t2, z2 = simulate_linear(m, 50, np.random.default_rng(5))
    t3, _ = simulate_linear(m, 50, np.random.default_rng(6))
    assert t1.shape == (50, 4) and z1.shape == (50, 2)
    np.testing.assert_array_equal(t1, t2)
    np.testing.assert_array_equal(z1, z2)
    assert not np.array_equal(t1, t3)


def test_simulate_follows_the_model_equations():
    """truth[k] = F truth[k-1] + w with Cov(w) = Q, z - H truth has Cov = R (sample check)."""
    F = np.array([[0.5, 0.2], [0.0, 0.3]])
    H = np.array([[1.0, 0.0], [1.0, 1.0]])
    Q = np.array([[0.2, 0.05], [0.05, 0.1]])
    R = np.array([[0.3, -0.1], [-0.1, 0.4]])
    m = LinearGaussianModel(F, H, Q, R)
    x0 = np.array([1.0, -2.0])
    truth, z = simulate_linear(m, 20_000, np.random.default_rng(1), x0=x0)
    prev = np.vstack([x0, truth[:-1]])
    w = truth - prev @ F.T
    v = z - truth @ H.T
    # 20 000 samples: covariance entries within ~4 standard errors
    np.testing.assert_allclose(np.cov(w.T), Q, atol=0.01)
    np.testing.assert_allclose(np.cov(v.T), R, atol=0.02)
    assert np.all(np.abs(w.mean(axis=0)) < 0.015) and np.all(np.abs(v.mean(axis=0)) < 0.02)


def test_simulate_rank_one_noise_stays_in_the_gain_direction():
    """With Q = sigma^2 G G^T the process noise lies along G (model B)."""
    m = assimakis_model_b(dt=1.0)
    truth, _ = simulate_linear(m, 200, np.random.default_rng(2))
    w = truth - np.vstack([np.zeros(2), truth[:-1]]) @ m.F.T
    # w = g * [dt/2, 1]: first component is half the second
    np.testing.assert_allclose(w[:, 0], 0.5 * w[:, 1], atol=1e-14)
