"""EKF, UKF and their RTS smoothers on :class:`mptrack.models.NonlinearModel` against FilterPy's and
Stone Soup's own implementations on identical inputs (issue 15): agreement to <= 1e-10."""

from datetime import datetime, timedelta

import numpy as np
import pytest

from mptrack.errors import ParameterError
from mptrack.models import NonlinearModel, constant_velocity, nonlinear_model, range_bearing
from mptrack.nonlinear import ekf_filter, ekf_smoother, particle_filter, ukf_filter, ukf_smoother

pytest.importorskip("stonesoup")
pytest.importorskip("filterpy")
from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter  # noqa: E402
from filterpy.kalman import rts_smoother as filterpy_rts  # noqa: E402
from stonesoup.models.measurement.nonlinear import CartesianToBearingRange  # noqa: E402
from stonesoup.models.transition.linear import (  # noqa: E402
    CombinedLinearGaussianTransitionModel,
    ConstantVelocity,
)
from stonesoup.predictor.kalman import ExtendedKalmanPredictor, UnscentedKalmanPredictor  # noqa: E402
from stonesoup.smoother.kalman import ExtendedKalmanSmoother, UnscentedKalmanSmoother  # noqa: E402
from stonesoup.types.detection import Detection  # noqa: E402
from stonesoup.types.hypothesis import SingleHypothesis  # noqa: E402
from stonesoup.types.state import GaussianState  # noqa: E402
from stonesoup.types.track import Track  # noqa: E402
from stonesoup.updater.kalman import ExtendedKalmanUpdater, UnscentedKalmanUpdater  # noqa: E402

Q_CV, DT, STEPS = 0.5, 1.0, 30
R_BR = np.diag([np.radians(1.0) ** 2, 4.0])       # bearing rad^2, range m^2
SENSOR = np.array([-50.0, 20.0])
X0 = np.array([100.0, 8.0, 150.0, -3.0])          # [x, vx, y, vy]
P0 = np.diag([50.0, 5.0, 50.0, 5.0])
TOL = 1e-10


def _model():
    return nonlinear_model(constant_velocity(DT, Q_CV, axes=2), range_bearing(SENSOR, R_BR))


def _data(seed=0):
    model = _model()
    rng = np.random.default_rng(seed)
    F, L = model.jac_f(X0), np.linalg.cholesky(model.Q)
    x, truth = X0.copy(), []
    for _ in range(STEPS):
        x = F @ x + L @ rng.standard_normal(4)
        truth.append(x)
    truth = np.array(truth)
    z = model.h(truth) + rng.standard_normal((STEPS, 2)) @ np.linalg.cholesky(R_BR).T
    return model, truth, z


class _AnalyticBearingRange(CartesianToBearingRange):
    """Stone Soup's model with the analytic Jacobian (its own is a finite difference, ~1e-8 relative):
    identical inputs for the EKF comparison."""

    def jacobian(self, state, **kwargs):
        return _model().jac_h(np.asarray(state.state_vector, dtype=float).ravel())


def _ss_models():
    tm = CombinedLinearGaussianTransitionModel([ConstantVelocity(Q_CV), ConstantVelocity(Q_CV)])
    mm = _AnalyticBearingRange(ndim_state=4, mapping=(0, 2), noise_covar=R_BR,
                               translation_offset=SENSOR[:, None])
    return tm, mm


def _ss_run(predictor, updater, z, mm):
    start = datetime(2024, 1, 1)
    state, track = GaussianState(X0[:, None], P0, timestamp=start), Track()
    for k in range(len(z)):
        t = start + timedelta(seconds=DT * (k + 1))
        pred = predictor.predict(state, timestamp=t)
        state = updater.update(SingleHypothesis(pred, Detection(z[k][:, None], timestamp=t, measurement_model=mm)))
        track.append(state)
    return track


def _arrays(track):
    return (np.array([np.asarray(s.state_vector, float).ravel() for s in track]),
            np.array([np.asarray(s.covar, float) for s in track]))


def test_same_cv_model_as_stonesoup():
    tm, _ = _ss_models()
    model = _model()
    np.testing.assert_allclose(model.jac_f(X0), tm.matrix(time_interval=timedelta(seconds=DT)), atol=0)
    np.testing.assert_allclose(model.Q, tm.covar(time_interval=timedelta(seconds=DT)), rtol=1e-14)


def test_ekf_bearing_range_matches_stonesoup_and_erts_its_smoother():
    model, _, z = _data(1)
    tm, mm = _ss_models()
    track = _ss_run(ExtendedKalmanPredictor(tm), ExtendedKalmanUpdater(mm), z, mm)
    res = ekf_filter(model, z, X0, P0)
    xs, Ps = _arrays(track)
    np.testing.assert_allclose(res.x, xs, rtol=0, atol=TOL * np.abs(xs).max())
    np.testing.assert_allclose(res.P, Ps, rtol=0, atol=TOL * np.abs(Ps).max())
    smooth = ekf_smoother(model, res)
    xs_s, Ps_s = _arrays(ExtendedKalmanSmoother(tm).smooth(track))
    np.testing.assert_allclose(smooth.x, xs_s, rtol=0, atol=TOL * np.abs(xs_s).max())
    np.testing.assert_allclose(smooth.P, Ps_s, rtol=0, atol=TOL * np.abs(Ps_s).max())
    assert smooth.x0 is not None and np.all(np.diagonal(smooth.P0) <= np.diag(P0))


@pytest.mark.parametrize("ut", [dict(alpha=0.5, beta=2.0, kappa=-1.0), dict(alpha=1.0, beta=2.0, kappa=0.0)])
def test_ukf_matches_stonesoup_and_urts_its_smoother(ut):
    model, _, z = _data(2)
    tm, mm = _ss_models()
    track = _ss_run(UnscentedKalmanPredictor(tm, **ut), UnscentedKalmanUpdater(mm, **ut), z, mm)
    res = ukf_filter(model, z, X0, P0, **ut)
    xs, Ps = _arrays(track)
    np.testing.assert_allclose(res.x, xs, rtol=0, atol=TOL * np.abs(xs).max())
    np.testing.assert_allclose(res.P, Ps, rtol=0, atol=TOL * np.abs(Ps).max())
    smooth = ukf_smoother(model, res, **ut)
    xs_s, Ps_s = _arrays(UnscentedKalmanSmoother(tm, **ut).smooth(track))
    np.testing.assert_allclose(smooth.x, xs_s, rtol=0, atol=TOL * np.abs(xs_s).max())
    np.testing.assert_allclose(smooth.P, Ps_s, rtol=0, atol=TOL * np.abs(Ps_s).max())


def _filterpy_ukf(model, z, ut):
    points = MerweScaledSigmaPoints(4, **ut)
    ukf = UnscentedKalmanFilter(4, 2, DT, fx=lambda x, dt: model.f(x[None])[0], hx=lambda x: model.h(x[None])[0],
                                points=points, residual_z=lambda a, b: model.innovation(a, b),
                                z_mean_fn=lambda Z, Wm: np.array([np.arctan2(Wm @ np.sin(Z[:, 0]),
                                                                             Wm @ np.cos(Z[:, 0])), Wm @ Z[:, 1]]))
    ukf.x, ukf.P, ukf.Q, ukf.R = X0.copy(), P0.copy(), np.array(model.Q), R_BR
    xs, Ps = [], []
    for zk in z:
        ukf.predict()
        # FilterPy reuses f(sigma points) in the update; redraw them from the prediction (Stone Soup/Särkkä)
        ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)
        ukf.update(zk)
        xs.append(ukf.x.copy())
        Ps.append(ukf.P.copy())
    return ukf, np.array(xs), np.array(Ps)


def test_ukf_merwe_radar_matches_filterpy_and_its_rts_smoother():
    ut = dict(alpha=0.3, beta=2.0, kappa=0.5)
    model, _, z = _data(3)
    ukf, xs, Ps = _filterpy_ukf(model, z, ut)
    res = ukf_filter(model, z, X0, P0, **ut)
    np.testing.assert_allclose(res.x, xs, rtol=0, atol=TOL * np.abs(xs).max())
    np.testing.assert_allclose(res.P, Ps, rtol=0, atol=TOL * np.abs(Ps).max())
    xs_s, Ps_s, _ = ukf.rts_smoother(xs, Ps)
    smooth = ukf_smoother(model, res, **ut)
    np.testing.assert_allclose(smooth.x, xs_s, rtol=0, atol=TOL * np.abs(xs_s).max())
    np.testing.assert_allclose(smooth.P, Ps_s, rtol=0, atol=TOL * np.abs(Ps_s).max())


def test_ekf_state_dependent_R_matches_filterpy_and_erts_filterpy_rts():
    """R grows with the range (R(x, k) evaluated at the prediction); FilterPy's EKF, which takes R per update."""
    base = _model()

    def R_of(x, k):
        rng = np.hypot(x[0] - SENSOR[0], x[2] - SENSOR[1])
        return np.diag([np.radians(1.0) ** 2, 1.0 + (0.02 * rng) ** 2])
    model = NonlinearModel(base.f, base.h, base.Q, R_of, jac_f=base.jac_f, jac_h=base.jac_h, angle_components=(0,))
    _, _, z = _data(4)
    ekf = ExtendedKalmanFilter(4, 2)
    ekf.x, ekf.P, ekf.F, ekf.Q = X0.copy(), P0.copy(), np.array(base.jac_f(X0)), np.array(base.Q)
    xs, Ps, xp, Pp = [], [], [], []
    for k, zk in enumerate(z):
        ekf.predict()
        xp.append(ekf.x.copy())
        Pp.append(ekf.P.copy())
        ekf.update(zk, HJacobian=base.jac_h, Hx=lambda x: base.h(x[None])[0], R=R_of(ekf.x, k),
                   residual=lambda a, b: base.innovation(a, b))
        xs.append(ekf.x.copy())
        Ps.append(ekf.P.copy())
    res = ekf_filter(model, z, X0, P0)
    xs, Ps = np.array(xs), np.array(Ps)
    np.testing.assert_allclose(res.x, xs, rtol=0, atol=TOL * np.abs(xs).max())
    np.testing.assert_allclose(res.P, Ps, rtol=0, atol=TOL * np.abs(Ps).max())
    np.testing.assert_allclose(res.P_pred, np.array(Pp), rtol=0, atol=TOL * np.abs(Ps).max())
    T = len(z)
    xs_s, Ps_s, _, _ = filterpy_rts(xs, Ps, np.repeat(ekf.F[None], T, 0), np.repeat(ekf.Q[None], T, 0))
    smooth = ekf_smoother(model, res)
    np.testing.assert_allclose(smooth.x, xs_s, rtol=0, atol=TOL * np.abs(xs_s).max())
    np.testing.assert_allclose(smooth.P, Ps_s, rtol=0, atol=TOL * np.abs(Ps_s).max())


def test_numeric_jacobians_match_analytic_ones():
    model, _, z = _data(5)
    numeric = NonlinearModel(model.f, model.h, model.Q, model.R, angle_components=(0,))
    a, b = ekf_filter(model, z, X0, P0), ekf_filter(numeric, z, X0, P0)
    np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-6)
    for x in a.x[::7]:
        np.testing.assert_allclose(numeric.H_at(x), model.jac_h(x), rtol=1e-7, atol=1e-12)


def test_prior_at_first_measurement_skips_the_first_prediction():
    model, _, z = _data(6)
    a = ekf_filter(model, z, X0, P0, prior="first-measurement")
    np.testing.assert_array_equal(a.x_pred[0], X0)
    b = ekf_filter(model, z[1:], a.x[0], a.P[0])  # continuing from the first update = the same filter
    np.testing.assert_allclose(b.x, a.x[1:], rtol=1e-13, atol=1e-9)
    assert a.x0 is None and ekf_smoother(model, a).x0 is None


def test_pf_ukf_ekf_agree_on_a_linear_gaussian_model():
    """On a linear-Gaussian model the EKF and UKF are the KF (to rounding) and the PF converges to it."""
    from mptrack.linear import kalman_filter
    lin = constant_velocity(DT, Q_CV, axes=2, sigma_r2=9.0)
    Ft, Ht = lin.F.T.copy(), lin.H.T.copy()
    model = NonlinearModel(lambda X: X @ Ft, lambda X: X @ Ht, lin.Q, lin.R)
    rng = np.random.default_rng(7)
    z = (np.arange(1, 21)[:, None] * np.array([8.0, -3.0])) + 3 * rng.standard_normal((20, 2))
    kf = kalman_filter(lin, z, X0 * 0, P0)
    for res in (ekf_filter(model, z, X0 * 0, P0), ukf_filter(model, z, X0 * 0, P0)):
        np.testing.assert_allclose(res.x, kf.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(res.P, kf.P, rtol=1e-9, atol=1e-9)
    errors = [np.sqrt(np.mean((particle_filter(model, z, X0 * 0, P0, np.random.default_rng(s), particles=N).x
                               - kf.x) ** 2)) for N, s in ((300, 1), (3000, 2), (30000, 3))]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.15


def test_bad_inputs_name_the_argument():
    model, _, z = _data(0)
    with pytest.raises(ParameterError, match="P0"):
        ekf_filter(model, z, X0, None)
    with pytest.raises(ParameterError, match="kappa"):
        ukf_filter(model, z, X0, P0, kappa=-4.0)
    with pytest.raises(ParameterError, match="alpha"):
        ukf_filter(model, z, X0, P0, alpha=0.0)
    with pytest.raises(ParameterError, match="prior"):
        ekf_filter(model, z, X0, P0, prior="start")
    with pytest.raises(ParameterError, match="substeps"):
        ukf_filter(model, z, X0, P0, substeps=3)
    with pytest.raises(ParameterError, match="n:"):
        NonlinearModel(model.f, model.h, lambda x, k: np.eye(4), R_BR)


def test_batch_ekf_equals_ekf_filter_per_track():
    from mptrack.nonlinear import ekf_filter_batch
    model, _, z = _data(8)
    rng = np.random.default_rng(9)
    zb = np.stack([z + rng.normal(0, [0.01, 1.0], z.shape) for _ in range(5)])
    zb[1, 4] = np.nan
    zb[2, 7, 0] = np.nan                                   # a missing bearing: update with the range only
    x0 = X0 + rng.normal(0, 3.0, (5, 4))
    batch = ekf_filter_batch(model, zb, x0, P0)
    for b in range(5):
        one = ekf_filter(model, zb[b], x0[b], P0)
        np.testing.assert_allclose(batch.x[b], one.x, rtol=1e-12, atol=1e-12 * np.abs(one.x).max())
        np.testing.assert_allclose(batch.P[b], one.P, rtol=1e-10, atol=1e-12 * np.abs(one.P).max())
        assert abs(batch.loglik[b] - one.loglik) <= 1e-12 * abs(one.loglik)
    with pytest.raises(ParameterError, match="constant Q and R"):
        ekf_filter_batch(NonlinearModel(model.f, model.h, model.Q, lambda x, k: R_BR), zb, x0, P0)
