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
        ukf.predict()   # FilterPy 1.4.4+ draws the update's sigma points from the prediction here, as we do
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


def _linear_with_step_Q(calls):
    """A linear CV model (position measured) with a step-indexed Q(x, k) = Qs[k] that records its calls."""
    lin = constant_velocity(DT, Q_CV, axes=2, sigma_r2=9.0)
    Qs = np.array([constant_velocity(DT, q, axes=2).Q for q in np.random.default_rng(11).uniform(0.1, 3.0, 20)])

    def Q_of(x, k):
        calls.append((k, np.array(x)))
        return Qs[k]
    Ft, Ht = lin.F.T.copy(), lin.H.T.copy()
    model = NonlinearModel(lambda X: X @ Ft, lambda X: X @ Ht, Q_of, lin.R, n=4, jac_f=lambda x: lin.F,
                           jac_h=lambda x: lin.H)
    z = np.arange(1, 21)[:, None] * np.array([8.0, -3.0]) + 3 * np.random.default_rng(12).standard_normal((20, 2))
    return lin, Qs, model, z


@pytest.mark.parametrize("prior", ["initial", "first-measurement"])
def test_smoothers_evaluate_step_indexed_Q_at_the_filters_step(prior):
    """Q(x, k) is the noise of the step into row k: a smoother must not evaluate it with another k than the
    filter's for the same state (they passed k + 1: an IndexError past the last row, or the wrong Q; now
    they take P(k+1/k) from the result and do not call Q at all).  On a linear model with Q(x, k) = Qs[k]
    the EKF/UKF are the time-varying KF and their smoothers its RTS."""
    from mptrack.linear import kalman_filter, rts_smoother
    calls = []
    lin, Qs, model, z = _linear_with_step_Q(calls)
    x0 = np.zeros(4)
    kf = kalman_filter(lin, z, x0, P0, Q=Qs, prior=prior)
    rts = rts_smoother(lin, kf, Q=Qs)
    for filt, smoother in ((ekf_filter, ekf_smoother), (ukf_filter, ukf_smoother)):
        calls.clear()
        res = filt(model, z, x0, P0, prior=prior)
        at_filter = list(calls)
        calls.clear()
        smooth = smoother(model, res)
        for k, x in calls:
            same = [kf_k for kf_k, kf_x in at_filter if np.array_equal(kf_x, x)]
            assert same == [k], (k, same)
        np.testing.assert_allclose(res.x, kf.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(smooth.x, rts.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(smooth.P, rts.P, rtol=1e-9, atol=1e-9)
        if prior == "initial":
            np.testing.assert_allclose(smooth.x0, rts.x0, rtol=0, atol=1e-9)


def test_ukf_smoother_refuses_other_sigma_point_parameters():
    """The unscented smoother's cross-covariances must come from the filter's sigma points: it reads
    them from the result, and other values are an error naming the parameter."""
    model, _, z = _data(2)
    ut = dict(alpha=0.5, beta=2.0, kappa=-1.0)
    res = ukf_filter(model, z, X0, P0, **ut)
    np.testing.assert_array_equal(ukf_smoother(model, res).x, ukf_smoother(model, res, **ut).x)
    with pytest.raises(ParameterError, match="alpha"):
        ukf_smoother(model, res, alpha=1.0)
    with pytest.raises(ParameterError, match="kappa"):
        ukf_smoother(model, ukf_filter(model, z, X0, P0), kappa=1.0)


def _complex_step_jacobian(h, x):
    J = np.empty((h(x[None]).shape[-1], x.shape[0]))
    for i in range(x.shape[0]):
        xc = x.astype(complex)
        xc[i] += 1e-30j
        J[:, i] = h(xc[None])[0].imag / 1e-30
    return J


@pytest.mark.parametrize("kind", ["range_rate_2d", "range_rate_3d", "tdoa", "tdoa_ref2"])
def test_range_rate_and_tdoa_jacobians_match_the_complex_step(kind):
    """The analytic Jacobians of range_rate and tdoa against complex-step derivatives of their h (exact to
    rounding) and the model's central differences, at random states (also one with a tiny range)."""
    from mptrack.models import range_rate, tdoa
    stations = np.array([[0.0, 0.0], [300.0, 10.0], [120.0, 250.0], [-80.0, 140.0]])
    meas, n, pos, near = {
        "range_rate_2d": (range_rate([10.0, -20.0], 0.25), 4, [0, 2], [10.0, -20.0]),
        "range_rate_3d": (range_rate([10.0, -20.0, 5.0], 0.25, position=(0, 2, 4), velocity=(1, 3, 5)), 6,
                          [0, 2, 4], [10.0, -20.0, 5.0]),
        "tdoa": (tdoa(stations, 4.0), 4, [0, 2], stations[1]),
        "tdoa_ref2": (tdoa(stations, 4.0, reference=2), 4, [0, 2], stations[2]),
    }[kind]
    rng = np.random.default_rng(13)
    states = rng.normal(0.0, 200.0, (25, n))
    states[0, pos] = np.asarray(near) + 1e-3                 # 1.7 mm from a station
    numeric = NonlinearModel(lambda X: X, meas.h, np.eye(n), meas.R)
    for x in states:
        J = meas.jac_h(x)
        np.testing.assert_allclose(J, _complex_step_jacobian(meas.h, x), rtol=1e-12, atol=1e-14)
        if np.linalg.norm(x[pos] - near) > 1.0:
            np.testing.assert_allclose(numeric.H_at(x), J, rtol=1e-6, atol=1e-9)
    batch = meas.jac_h(states)
    np.testing.assert_allclose(batch, np.stack([meas.jac_h(x) for x in states]), rtol=0, atol=0)


@pytest.mark.parametrize("filt", [ekf_filter, ukf_filter])
def test_generic_path_errors_name_the_cause(filt):
    """The compiled step kernels report problems by status; the errors still name the cause: an
    indefinite innovation covariance, a model function returning NaN or a wrong shape, an overflow."""
    from mptrack.errors import NonFiniteError, NotPositiveDefiniteError, ShapeError
    base, _, z = _data(0)

    def model(**kw):
        args = dict(f=base.f, h=base.h, Q=base.Q, R=R_BR, jac_f=base.jac_f, jac_h=base.jac_h, angle_components=(0,))
        args.update(kw)
        return NonlinearModel(args.pop("f"), args.pop("h"), args.pop("Q"), args.pop("R"), **args)
    with pytest.raises(NotPositiveDefiniteError, match=f"{filt.__name__[:3].upper()}.*measurement 5"):
        filt(model(R=lambda x, k: -np.eye(2) * 1e6 if k == 5 else R_BR), z, X0, P0)

    def h_nan(X):
        out = base.h(X)
        return np.where(X[..., :1] > 140.0, np.nan, out)
    with pytest.raises(NonFiniteError, match="^h: "):
        filt(model(h=h_nan), z, X0, P0)
    with pytest.raises(ShapeError, match="jac_h" if filt is ekf_filter else "^h: "):
        wrong = (dict(jac_h=lambda x: np.zeros((3, 4)) if x[0] > 140.0 else base.jac_h(x)) if filt is ekf_filter
                 else dict(h=lambda X: base.h(X) if X.shape[0] < 9 else base.h(X)[:, :1]))
        filt(model(**wrong), z, X0, P0)
    with pytest.raises(NonFiniteError, match="x0"):
        filt(model(), z, np.array([1e308, 1e308, 1.0, 1.0]), P0)
