"""The compiled EKF/UKF for linear motion + named measurement models equal the NumPy path (to 1e-10) on
identical inputs: angle wrapping across ±π, NaN components and rows, both priors, the batch form, and the
fallback to the NumPy path when the kernel cannot take a Cholesky factor."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.models import (
    NonlinearModel,
    bearings,
    constant_velocity,
    nonlinear_model,
    position,
    range_bearing,
    range_rate,
    ranges,
    stack_measurements,
    tdoa,
)
from mptrack.nonlinear import ekf_filter, ekf_filter_batch, ukf_filter
from mptrack.nonlinear._extended import _ekf_batch_core

SIG_B, SIG_R = np.radians(1.0), 2.0


def generic(model):
    """The same model without the kernel tag: the NumPy path."""
    twin = dataclasses.replace(model)
    assert twin.named is None
    return twin


def models():
    cv2 = constant_velocity(1.0, 0.5, axes=2)
    cv3 = constant_velocity(1.0, 0.5, axes=3)
    return {
        "range_bearing": nonlinear_model(cv2, range_bearing([0.0, 0.0], np.diag([SIG_B ** 2, SIG_R ** 2]))),
        "ranges": nonlinear_model(cv2, ranges([[0.0, 0.0], [300.0, 0.0], [0.0, 300.0]], 4.0)),
        "bearings": nonlinear_model(cv2, bearings([[0.0, 0.0], [-200.0, 100.0]], SIG_B ** 2)),
        "position": nonlinear_model(cv2, position([25.0, 16.0])),
        "ranges 3-D": nonlinear_model(cv3, ranges([[0.0, 0.0, 30.0], [300.0, 0.0, 0.0], [0.0, 300.0, 10.0]], 4.0,
                                                  position=(0, 2, 4))),
        "TOA + AOA + GPS": nonlinear_model(cv2, stack_measurements(
            ranges([[0.0, 0.0], [300.0, 0.0]], [4.0, 9.0]), bearings([0.0, 0.0], SIG_B ** 2),
            position(np.array([[25.0, 5.0], [5.0, 16.0]])))),
    }


def scenario(model, seed=3, T=60):
    """A track passing behind the sensor at the origin (bearings cross ±π), noisy measurements with NaN
    components and a NaN row."""
    rng = np.random.default_rng(seed)
    n = model.n
    x = np.zeros(n)
    x[:4] = [-150.0, 0.5, 3.0, -0.1]
    xs = [x]
    for _ in range(T - 1):
        xs.append(model.f(xs[-1][None])[0] + rng.standard_normal(n) * 0.05)
    truth = np.array(xs)
    z = model.h(truth) + rng.standard_normal((T, model.m)) @ np.linalg.cholesky(model.R).T
    for i in model.angle_components:
        z[:, i] = (z[:, i] + np.pi) % (2 * np.pi) - np.pi
    z[4] = np.nan
    z[9, 0] = np.nan
    z[17, -1] = np.nan
    P0 = np.diag(np.tile([100.0, 4.0], n // 2))
    return z, truth[0] + rng.standard_normal(n) * 3.0, P0


def assert_same(a, b, tol=1e-10):
    for f in ("x", "P", "x_pred", "P_pred", "innovation", "S", "nis"):
        got, want = getattr(a, f), getattr(b, f)
        assert got.shape == want.shape
        assert np.array_equal(np.isnan(got), np.isnan(want)), f
        assert np.nanmax(np.abs(got - want) / (1.0 + np.abs(want))) < tol, f
    assert abs(a.loglik - b.loglik) < tol * (1.0 + abs(b.loglik))
    for f in ("x0", "P0"):
        assert (getattr(a, f) is None) == (getattr(b, f) is None)


@pytest.mark.parametrize("name", list(models()))
@pytest.mark.parametrize("prior", ["initial", "first-measurement"])
@pytest.mark.parametrize("method", ["ekf", "ukf"])
def test_kernel_equals_numpy_path(name, prior, method):
    model = models()[name]
    assert model.named is not None
    z, x0, P0 = scenario(model)
    run = (lambda m: ekf_filter(m, z, x0, P0, prior=prior)) if method == "ekf" else \
        (lambda m: ukf_filter(m, z, x0, P0, prior=prior, alpha=0.5, beta=2.0, kappa=-1.0))
    fast, slow = run(model), run(generic(model))
    assert_same(fast, slow)
    assert np.isfinite(fast.loglik)


def test_bearings_really_wrap():
    """The scenario's bearings cross ±π, so a missing wrap would change the estimates."""
    model = models()["range_bearing"]
    z, _, _ = scenario(model)
    b = z[~np.isnan(z[:, 0]), 0]
    assert np.sum(np.abs(np.diff(b)) > np.pi) >= 5


@pytest.mark.parametrize("name", ["range_bearing", "TOA + AOA + GPS"])
def test_batch_kernel_equals_numpy_batch_and_single_runs(name):
    model = models()[name]
    runs = [scenario(model, seed=s, T=40) for s in range(5)]
    z = np.stack([r[0] for r in runs])
    x0 = np.stack([r[1] for r in runs])
    P0 = runs[0][2]
    fast = ekf_filter_batch(model, z, x0, P0)
    xs, Ps, xp, Pp, ll, nu, S, nis = _ekf_batch_core(model, z, x0.copy(),
                                                     np.broadcast_to(P0, (5,) + P0.shape).copy())
    for got, want in ((fast.x, xs), (fast.P, Ps), (fast.x_pred, xp), (fast.P_pred, Pp), (fast.loglik, ll),
                      (fast.innovation, nu), (fast.S, S), (fast.nis, nis)):
        assert np.array_equal(np.isnan(got), np.isnan(want))
        assert np.nanmax(np.abs(got - want) / (1.0 + np.abs(want))) < 1e-10
    for b in (0, 3):
        one = ekf_filter(model, z[b], x0[b], P0)
        assert np.max(np.abs(fast.x[b] - one.x) / (1.0 + np.abs(one.x))) < 1e-10
        np.testing.assert_allclose(fast.nis[b], one.nis, rtol=1e-10)
        assert abs(fast.loglik[b] - one.loglik) < 1e-10 * abs(one.loglik)


def test_ukf_semidefinite_prior_falls_back_to_numpy_path():
    """A singular P0 has no Cholesky factor: the kernel hands over to the NumPy path (eigenvalue root)."""
    model = models()["range_bearing"]
    z, x0, _ = scenario(model)
    P0 = np.diag([100.0, 0.0, 100.0, 0.0])
    assert_same(ukf_filter(model, z, x0, P0), ukf_filter(generic(model), z, x0, P0))


def test_only_named_linear_models_are_tagged():
    cv = constant_velocity(1.0, 0.5, axes=2)
    assert nonlinear_model(cv, tdoa([[0.0, 0.0], [300.0, 0.0], [0.0, 300.0]], 4.0)).named is None
    assert nonlinear_model(cv, range_rate([0.0, 0.0], 1.0)).named is None
    assert nonlinear_model(cv, range_bearing([0.0, 0.0], lambda x, k: np.eye(2))).named is None
    assert nonlinear_model(cv, stack_measurements(ranges([0.0, 0.0], 1.0),
                                                  range_rate([0.0, 0.0], 1.0))).named is None
    user = NonlinearModel(lambda X: X, lambda X: X[..., :1], np.eye(2), np.eye(1))
    assert user.named is None
    _, codes, pos, _ = models()["range_bearing"].named
    assert codes.tolist() == [1, 0] and pos.tolist() == [[0, 2, -1], [0, 2, -1]]
    with pytest.raises(ValueError):
        codes[0] = 5                                                    # read-only


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), sx=st.floats(-500, 500), sy=st.floats(-500, 500),
       sig=st.floats(0.1, 20.0))
def test_ekf_kernel_equals_numpy_path_anywhere(seed, sx, sy, sig):
    model = nonlinear_model(constant_velocity(1.0, 0.5, axes=2),
                            range_bearing([sx, sy], np.diag([(sig * 1e-3) ** 2, sig ** 2])))
    z, x0, P0 = scenario(model, seed=seed, T=25)
    assert_same(ekf_filter(model, z, x0, P0), ekf_filter(generic(model), z, x0, P0), tol=1e-9)
