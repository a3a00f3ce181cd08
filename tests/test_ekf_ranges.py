"""EKF on base-station ranges: Jacobians vs finite differences, equivalence with the linear KF step,
missing ranges, batching and bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.cellular import ekf_ranges, ekf_ranges_batch, motion_matrix, range_measurement
from mptrack.errors import NonFiniteError, ParameterError, ShapeError
from mptrack.linear import kalman_step

STATIONS = np.array([[0.0, 0.0, 0.03], [2.0, 0.0, 0.03], [1.0, 1.7, 0.03]])
Q0 = np.diag([0.02, 0.02, 0.002])


def _track(T=40, seed=0, sigma=0.001):
    rng = np.random.default_rng(seed)
    t = np.arange(1, T + 1)
    truth = np.stack([0.3 + 0.01 * t, 0.4 + 0.005 * t, np.full(T, 0.0015)], 1)
    z = np.linalg.norm(truth[:, None, :] - STATIONS, axis=-1) + sigma * rng.standard_normal((T, 3))
    return truth, z


@pytest.mark.parametrize("n", [3, 6])
def test_jacobian_matches_central_differences(n):
    rng = np.random.default_rng(1)
    for _ in range(20):
        x = rng.uniform(-1, 3, n)
        _, H = range_measurement(x, STATIONS)
        eps = 1e-6
        num = np.stack([(range_measurement(x + eps * e, STATIONS)[0] - range_measurement(x - eps * e, STATIONS)[0])
                        / (2 * eps) for e in np.eye(n)], axis=1)
        np.testing.assert_allclose(H, num, atol=1e-8)
        if n == 6:
            assert np.all(H[:, 3:] == 0)


def test_jacobian_2d_and_batched_shapes():
    st2 = STATIONS[:, :2]
    x = np.random.default_rng(2).uniform(0, 1, (5, 7, 2))
    r, H = range_measurement(x, st2)
    assert r.shape == (5, 7, 3) and H.shape == (5, 7, 3, 2)
    np.testing.assert_allclose(np.linalg.norm(H, axis=-1), 1.0)


def test_one_step_equals_kalman_step_on_the_linearised_measurement():
    truth, z = _track(T=1)
    x0 = truth[0] + np.array([0.02, -0.03, 0.0])
    P0 = 1e-3 * np.eye(3)
    res = ekf_ranges(z, STATIONS, x0, P0, Q0, 0.222)
    h, H = range_measurement(x0, STATIONS)  # x(1/0) = x0 for the random walk
    z_lin = z[0] - h + H @ x0
    x1, P1, *_ = kalman_step(np.eye(3), H, Q0, 0.222 * np.eye(3), x0, P0, z_lin)
    np.testing.assert_allclose(res.x[0], x1, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(res.P[0], P1, rtol=1e-10, atol=1e-14)


def test_tracks_a_moving_terminal():
    truth, z = _track(T=80)
    res = ekf_ranges(z, STATIONS, truth[0], 1e-3 * np.eye(3), Q0, 0.222)
    err = np.linalg.norm(res.x - truth, axis=1)
    assert err[-20:].mean() < 0.05  # km
    assert np.isfinite(res.loglik)


def test_constant_velocity_beats_random_walk_on_a_straight_line():
    truth, z = _track(T=80, sigma=0.01)
    rw = ekf_ranges(z, STATIONS, truth[0], 1e-3 * np.eye(3), Q0, 1e-4)
    q = 1e-7
    Qcv = np.kron(np.eye(3), np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]]) * q)   # state [x, vx, y, vy, z, vz]
    x0 = np.ravel(np.column_stack([truth[0], [0.01, 0.005, 0.0]]))
    cv = ekf_ranges(z, STATIONS, x0, np.diag([1e-3, 1e-5] * 3), Qcv, 1e-4, motion="cv", dt=1.0)
    e_rw = np.linalg.norm(rw.x - truth, axis=1)[20:].mean()
    e_cv = np.linalg.norm(cv.x[:, [0, 2, 4]] - truth, axis=1)[20:].mean()
    # the single-track EKF (ekf_filter on a ranges model) is the batch core's track to 1e-12
    for motion, xx, PP, QQ, res in (("random-walk", truth[0], 1e-3 * np.eye(3), Q0, rw),
                                    ("cv", x0, np.diag([1e-3, 1e-5] * 3), Qcv, cv)):
        zz = z.copy()
        zz[[3, 9], 1] = np.nan
        one = ekf_ranges(zz, STATIONS, xx, PP, QQ, 1e-4, motion=motion, dt=1.0)
        many = ekf_ranges_batch(zz[None], STATIONS, xx[None], PP, QQ, 1e-4, motion=motion, dt=1.0).run(0)
        np.testing.assert_allclose(one.x, many.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(one.P, many.P, rtol=1e-10, atol=1e-15)
        assert abs(one.loglik - many.loglik) <= 1e-12 * abs(many.loglik)
    assert e_cv < e_rw


def test_missing_range_equals_dropping_the_station():
    truth, z = _track(T=15)
    zz = z.copy()
    zz[5:9, 1] = np.nan
    full = ekf_ranges(zz, STATIONS, truth[0], 1e-3 * np.eye(3), Q0, 0.222)
    part = ekf_ranges(z[:5], STATIONS, truth[0], 1e-3 * np.eye(3), Q0, 0.222)
    np.testing.assert_allclose(full.x[:5], part.x)
    # step 5 with station 1 missing equals a one-step run on stations 0 and 2 from the same prior
    drop = ekf_ranges(z[5:6, [0, 2]], STATIONS[[0, 2]], part.x[-1], part.P[-1], Q0, 0.222)
    np.testing.assert_allclose(full.x[5], drop.x[0], rtol=1e-12)
    # an all-missing row only predicts
    zz[10] = np.nan
    res = ekf_ranges(zz, STATIONS, truth[0], 1e-3 * np.eye(3), Q0, 0.222)
    np.testing.assert_allclose(res.x[10], res.x[9])
    np.testing.assert_allclose(res.P[10], res.P[9] + Q0)
    assert np.isfinite(res.x).all()


def test_batch_equals_single_runs():
    runs = [_track(T=12, seed=s) for s in range(4)]
    z = np.stack([r[1] for r in runs])
    x0 = np.stack([r[0][0] for r in runs])
    batch = ekf_ranges_batch(z, STATIONS, x0, 1e-3 * np.eye(3), Q0, 0.222)
    for b in range(4):
        single = ekf_ranges(z[b], STATIONS, x0[b], 1e-3 * np.eye(3), Q0, 0.222)
        np.testing.assert_allclose(batch.x[b], single.x, rtol=1e-12)
        assert batch.run(b).loglik == pytest.approx(single.loglik)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.floats(1e-4, 1.0))
def test_covariances_stay_symmetric_psd(seed, r):
    truth, z = _track(T=10, seed=seed, sigma=0.05)
    res = ekf_ranges(np.abs(z), STATIONS, truth[0], 1e-3 * np.eye(3), Q0, r)
    np.testing.assert_allclose(res.P, res.P.transpose(0, 2, 1))
    assert np.linalg.eigvalsh(res.P).min() > 0


def test_bad_input():
    truth, z = _track(T=5)
    args = (truth[0], 1e-3 * np.eye(3), Q0, 0.222)
    dup = STATIONS.copy()
    dup[2] = dup[0]
    with pytest.raises(ParameterError, match="stations: stations 0 and 2"):
        ekf_ranges(z, dup, *args)
    with pytest.raises(ShapeError, match="z"):
        ekf_ranges(z[:, :2], STATIONS, *args)
    with pytest.raises(ShapeError, match="stations"):
        ekf_ranges(z, np.zeros((3, 4)), *args)
    with pytest.raises(ParameterError, match="z: ranges"):
        ekf_ranges(-z, STATIONS, *args)
    with pytest.raises(NonFiniteError, match="z"):
        ekf_ranges(np.where(z > 0, np.inf, z), STATIONS, *args)
    with pytest.raises(ParameterError, match="motion"):
        ekf_ranges(z, STATIONS, *args, motion="ballistic")
    with pytest.raises(ShapeError, match="x0"):
        ekf_ranges(z, STATIONS, np.zeros(2), *args[1:])
    with pytest.raises(ParameterError, match="dt"):
        motion_matrix("cv", 2, dt=-1.0)


def test_range_fix_2d_3d_and_with_known_height():
    from mptrack.errors import SingularMatrixError
    from mptrack.cellular import range_fix

    p = np.array([0.7, 0.5, 0.0015])
    z = np.linalg.norm(p - STATIONS, axis=1)
    np.testing.assert_allclose(range_fix(z, STATIONS, height=0.0015), p, atol=1e-10)
    np.testing.assert_allclose(range_fix(np.linalg.norm(p[:2] - STATIONS[:, :2], axis=1), STATIONS[:, :2]), p[:2],
                               atol=1e-10)
    st4 = np.vstack([STATIONS, [1.0, 0.5, 0.5]])
    np.testing.assert_allclose(range_fix(np.linalg.norm(p - st4, axis=1), st4), p, atol=1e-8)
    with pytest.raises(ParameterError, match="at least 3 stations"):
        range_fix(z[:2], STATIONS[:2, :2])
    with pytest.raises(ParameterError, match="at least 4 stations"):
        range_fix(z, STATIONS)
    line = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    with pytest.raises(SingularMatrixError, match="collinear"):
        range_fix([1.0, 1.0, 1.0], line)


def test_wild_ranges_never_give_nan_estimates():
    from mptrack.cellular import fcs_ranges, fekf_ranges

    rng = np.random.default_rng(9)
    truth, z = _track(T=30)
    wild = np.abs(z + rng.standard_normal(z.shape) * 2.0)
    wild[rng.uniform(size=wild.shape) < 0.2] = np.nan
    for run in (ekf_ranges, fekf_ranges, fcs_ranges):
        res = run(wild, STATIONS, truth[0], 1e-3 * np.eye(3), Q0, 0.222)
        assert np.isfinite(res.x).all() and np.isfinite(res.P).all()


def test_predictions_are_recorded():
    truth, z = _track(T=6)
    res = ekf_ranges(z, STATIONS, truth[0], 1e-3 * np.eye(3), Q0, 0.222)
    np.testing.assert_allclose(res.x_pred[1:], res.x[:-1])          # random walk: x(k/k-1) = x(k-1/k-1)
    np.testing.assert_allclose(res.P_pred[1:], res.P[:-1] + Q0)
    np.testing.assert_allclose(res.x_pred[0], truth[0])


@pytest.mark.parametrize("motion", ["random-walk", "cv"])
def test_range_ekf_runs_the_compiled_named_model_with_the_generic_numbers(motion):
    """ekf_ranges / ekf_ranges_batch build nonlinear_model(motion, ranges(...)), which the compiled named
    kernels run; the generic (untagged) path of the same model gives the same numbers to 1e-12."""
    import dataclasses

    from mptrack.nonlinear import ekf_filter, ekf_filter_batch
    from mptrack.cellular._ekf import _prepare, _ranges_model
    runs = [_track(T=15, seed=s) for s in range(3)]
    z = np.stack([r[1] for r in runs])
    z[1, 4, 2] = np.nan
    n = 3 if motion == "random-walk" else 6
    start = np.stack([r[0][0] for r in runs])
    x0 = start if n == 3 else np.stack([start, np.zeros((3, 3))], -1).reshape(3, 6)   # [x, vx, y, vy, z, vz]
    P0, Q = 1e-3 * np.eye(n), 1e-3 * np.eye(n)
    prepared = _prepare(z, STATIONS, x0, P0, Q, 0.222, motion, 1.0, batch=True)
    model = _ranges_model(*prepared[1:2], *prepared[4:], motion)
    assert model.named is not None
    generic = dataclasses.replace(model)
    assert generic.named is None
    batch = ekf_ranges_batch(z, STATIONS, x0, P0, Q, 0.222, motion=motion)
    for b in range(3):
        single = ekf_ranges(z[b], STATIONS, x0[b], P0, Q, 0.222, motion=motion)
        ref = ekf_filter(generic, z[b], x0[b], P0)
        for res in (single, batch.run(b)):
            np.testing.assert_allclose(res.x, ref.x, rtol=1e-12, atol=1e-12 * np.abs(ref.x).max())
            np.testing.assert_allclose(res.P, ref.P, rtol=1e-12, atol=1e-12 * np.abs(ref.P).max())
            assert res.loglik == pytest.approx(ref.loglik, rel=1e-12)
    np.testing.assert_allclose(ekf_filter_batch(generic, z, x0, P0).x, batch.x, rtol=1e-12, atol=1e-12)
