"""Linear-filter extras of issue 15 against FilterPy on identical inputs: control input B u, time-varying
F/H/Q/R, the prior at the first measurement, x(0/T) from the RTS smoother, no silent P0 = 0."""

import dataclasses

import numpy as np
import pytest

from mptrack.errors import ParameterError, ShapeError
from mptrack.linear import kalman_filter, rts_smoother
from mptrack.models import constant_velocity

filterpy = pytest.importorskip("filterpy")
from filterpy.kalman import KalmanFilter  # noqa: E402
from filterpy.kalman import rts_smoother as filterpy_rts  # noqa: E402

T, TOL = 40, 1e-10


def _setup(seed=0):
    model = constant_velocity(1.0, 0.3, axes=2, sigma_r2=4.0)
    rng = np.random.default_rng(seed)
    z = np.cumsum(rng.standard_normal((T, 2)), axis=0) * 3.0
    x0, P0 = np.array([1.0, 0.5, -2.0, 0.1]), np.diag([10.0, 2.0, 10.0, 2.0])
    return model, z, x0, P0


def _time_varying(model, seed=1):
    rng = np.random.default_rng(seed)
    dts = rng.uniform(0.5, 2.0, T)
    Fs = np.array([constant_velocity(dt, 0.3, axes=2).F for dt in dts])
    Qs = np.array([constant_velocity(dt, 0.3, axes=2).Q for dt in dts])
    Hs = np.repeat(model.H[None], T, 0)
    Hs[::3] = np.array([[1.0, 0, 0.2, 0], [0, 0, 1.0, 0.1]])   # a different sensor every third step
    Rs = np.array([np.diag([s, 2 * s]) for s in rng.uniform(1.0, 9.0, T)])
    return Fs, Hs, Qs, Rs


def _close(a, b):
    np.testing.assert_allclose(a, b, rtol=0, atol=TOL * max(np.abs(b).max(), 1.0))


def _filterpy(model, z, x0, P0, Fs, Hs, Qs, Rs, Bs=None, us=None):
    kf = KalmanFilter(model.n, model.m)
    kf.x, kf.P = x0.copy(), P0.copy()
    xs, Ps, _, _ = kf.batch_filter(z, Fs=Fs, Qs=Qs, Hs=Hs, Rs=Rs, Bs=Bs, us=us)
    return xs, Ps


def test_control_input_matches_filterpy_and_smoother_uses_it():
    model, z, x0, P0 = _setup()
    B = np.array([[0.5, 0.0], [1.0, 0.0], [0.0, 0.5], [0.0, 1.0]])    # acceleration input
    u = np.random.default_rng(2).standard_normal((T, 2))
    ours = kalman_filter(model, z, x0, P0, B=B, u=u)
    Fs, Qs = [model.F] * T, [model.Q] * T
    xs, Ps = _filterpy(model, z, x0, P0, Fs, [model.H] * T, Qs, [model.R] * T, Bs=[B] * T, us=u)
    _close(ours.x, xs)
    _close(ours.P, Ps)
    # oracle: x(k) = y(k) + d(k) with d(k) = F d(k-1) + B u(k), d(0) = 0 the known response to the input
    # and y the uncontrolled model measured by z - H d: filter and smoother shift by d exactly
    d = np.zeros((T, 4))
    for k in range(T):
        d[k] = model.F @ (d[k - 1] if k else np.zeros(4)) + B @ u[k]
    plain = kalman_filter(model, z - d @ model.H.T, x0, P0)
    _close(ours.x, plain.x + d)
    sm, sm_plain = rts_smoother(model, ours, B=B, u=u), rts_smoother(model, plain)
    _close(sm.x, sm_plain.x + d)
    _close(sm.P, sm_plain.P)
    _close(sm.x0, sm_plain.x0)
    # the run records B u: the smoother uses it without being told (the model alone has no control)
    _close(rts_smoother(model, ours).x, sm.x)
    assert np.abs(rts_smoother(model, dataclasses.replace(ours, inputs=None)).x - sm.x).max() > 1e-3


def test_time_varying_model_matches_filterpy_and_its_rts():
    model, z, x0, P0 = _setup(3)
    Fs, Hs, Qs, Rs = _time_varying(model)
    ours = kalman_filter(model, z, x0, P0, F=Fs, H=Hs, Q=Qs, R=Rs)
    xs, Ps = _filterpy(model, z, x0, P0, Fs, Hs, Qs, Rs)
    _close(ours.x, xs)
    _close(ours.P, Ps)
    sm = rts_smoother(model, ours, F=Fs, Q=Qs)
    # FilterPy's rts_smoother takes Fs[k] as the step from row k to row k+1: shift by one
    xs_s, Ps_s, _, _ = filterpy_rts(xs, Ps, np.concatenate([Fs[1:], Fs[:1]]), np.concatenate([Qs[1:], Qs[:1]]))
    _close(sm.x, xs_s)
    _close(sm.P, Ps_s)


def test_rts_x0_given_T_equals_whole_trajectory_least_squares():
    model, z, x0, P0 = _setup(4)
    res = kalman_filter(model, z, x0, P0)
    sm = rts_smoother(model, res)
    # whole-trajectory least squares over x(0..T): prior on x(0), transitions, measurements of x(1..T)
    H, R = model.H, model.R
    n = model.n
    J = np.zeros(((T + 1) * n, (T + 1) * n))
    h = np.zeros((T + 1) * n)
    blk = lambda k: slice(k * n, (k + 1) * n)  # noqa: E731
    J[blk(0), blk(0)] += np.linalg.inv(P0)
    h[blk(0)] += np.linalg.solve(P0, x0)
    Qi, Ri = np.linalg.inv(model.Q), np.linalg.inv(R)
    for k in range(1, T + 1):
        a, b = blk(k - 1), blk(k)
        J[a, a] += model.F.T @ Qi @ model.F
        J[a, b] -= model.F.T @ Qi
        J[b, a] -= Qi @ model.F
        J[b, b] += Qi + H.T @ Ri @ H
        h[b] += H.T @ Ri @ z[k - 1]
    cov = np.linalg.inv(J)
    mean = (cov @ h).reshape(T + 1, n)
    np.testing.assert_allclose(sm.x0, mean[0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(sm.P0, cov[blk(0), blk(0)], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(sm.x, mean[1:], rtol=1e-9, atol=1e-9)


def test_prior_at_first_measurement_matches_filterpys_update_first_loop():
    model, z, x0, P0 = _setup(5)
    ours = kalman_filter(model, z, x0, P0, prior="first-measurement")
    kf = KalmanFilter(4, 2)
    kf.x, kf.P, kf.F, kf.H, kf.Q, kf.R = x0.copy(), P0.copy(), model.F, model.H, model.Q, model.R
    xs, Ps = [], []
    for k, zk in enumerate(z):
        if k:
            kf.predict()
        kf.update(zk)
        xs.append(kf.x.copy())
        Ps.append(kf.P.copy())
    _close(ours.x, np.array(xs))
    _close(ours.P, np.array(Ps))
    assert ours.x0 is None and rts_smoother(model, ours).x0 is None


def test_p0_is_required_and_stacks_are_checked():
    model, z, x0, P0 = _setup()
    with pytest.raises(ParameterError, match="P0"):
        kalman_filter(model, z, x0)
    with pytest.raises(ShapeError, match="F"):
        kalman_filter(model, z, x0, P0, F=np.zeros((T - 1, 4, 4)))
    with pytest.raises(ParameterError, match="B and u"):
        kalman_filter(model, z, x0, P0, B=np.eye(4))
    with pytest.raises(ParameterError, match="prior"):
        kalman_filter(model, z, x0, P0, prior="first")


def test_smoother_reads_what_a_time_varying_or_controlled_filter_ran_with():
    """rts_smoother(model, result) after a time-varying or controlled kalman_filter run uses the run's
    F, Q and B u (recorded in result.inputs), not the model's constant F and Q (metres off before);
    matrices passed again must be the run's (else a ParameterError naming them)."""
    model, z, x0, P0 = _setup(6)
    Fs, Hs, Qs, Rs = _time_varying(model, seed=7)
    B = np.array([[0.5, 0.0], [1.0, 0.0], [0.0, 0.5], [0.0, 1.0]])
    u = np.random.default_rng(8).standard_normal((T, 2))
    for prior in ("initial", "first-measurement"):
        tv = kalman_filter(model, z, x0, P0, F=Fs, H=Hs, Q=Qs, R=Rs, prior=prior)
        explicit = rts_smoother(model, tv, F=Fs, Q=Qs)
        _close(rts_smoother(model, tv).x, explicit.x)
        _close(rts_smoother(model, tv).P, explicit.P)
        ctl = kalman_filter(model, z, x0, P0, B=B, u=u, prior=prior)
        explicit = rts_smoother(model, ctl, B=B, u=u)
        _close(rts_smoother(model, ctl).x, explicit.x)
        if prior == "initial":
            _close(rts_smoother(model, tv).x0, rts_smoother(model, tv, F=Fs, Q=Qs).x0)
            _close(rts_smoother(model, ctl).x0, explicit.x0)
    xs_s, _, _, _ = filterpy_rts(*_filterpy(model, z, x0, P0, Fs, Hs, Qs, Rs), np.concatenate([Fs[1:], Fs[:1]]),
                                 np.concatenate([Qs[1:], Qs[:1]]))
    _close(rts_smoother(model, kalman_filter(model, z, x0, P0, F=Fs, H=Hs, Q=Qs, R=Rs)).x, xs_s)
    with pytest.raises(ParameterError, match="Q"):
        rts_smoother(model, tv, Q=2.0 * Qs)
    with pytest.raises(ParameterError, match="F"):
        rts_smoother(model, tv, F=model.F)
    with pytest.raises(ParameterError, match="B and u"):
        rts_smoother(model, ctl, B=B, u=2.0 * u)
