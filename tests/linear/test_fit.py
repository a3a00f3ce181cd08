"""Parameter learning: EM (fit_em) and direct likelihood maximisation (fit_ml).

Oracles: pykalman's EM on identical inputs (its robot data set and a simulated track; the same
algorithm, so the same numbers to rounding), the MATLAB EM whose log-likelihoods and fitted covariances
ship with that data set (an independent implementation), and each other (EM and direct maximisation
reach the same maximum of the same likelihood).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mptrack.errors import NonFiniteError, NotPositiveDefiniteError, ParameterError, ShapeError
from mptrack.linear import FitResult, fit_em, fit_ml, kalman_filter
from mptrack.models import LinearGaussianModel, constant_velocity, cv_discrete_white_noise
from mptrack.sim import simulate_linear

pykalman = pytest.importorskip("pykalman")
from pykalman.datasets import load_robot  # noqa: E402

#: pykalman's names of what EM fits
PYKALMAN = {"F": "transition_matrices", "H": "observation_matrices", "Q": "transition_covariance",
            "R": "observation_covariance", "x0": "initial_state_mean", "P0": "initial_state_covariance"}
#: the same algorithm on the same inputs: the fitted matrices agree to rounding accumulated over the
#: iterations (1e-10 measured), far inside this
SAME = 1e-8


def _rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b)))


def _pykalman_em(start, obs, x0, P0, estimate, iterations, **kw):
    """pykalman's EM, one iteration at a time: its log-likelihood before each iteration and after the last."""
    kf = pykalman.KalmanFilter(start.F, start.H, start.Q, start.R, initial_state_mean=x0,
                               initial_state_covariance=P0, em_vars=[PYKALMAN[e] for e in estimate], **kw)
    loglik = [kf.loglikelihood(obs)]
    for _ in range(iterations):
        kf.em(obs, n_iter=1)
        loglik.append(kf.loglikelihood(obs))
    return kf, np.array(loglik)


def _assert_same_fit(fit, kf, loglik, estimate):
    assert _rel(fit.loglik, loglik) < SAME
    ours = {"F": fit.model.F, "H": fit.model.H, "Q": fit.model.Q, "R": fit.model.R, "x0": fit.x0, "P0": fit.P0}
    for name in estimate:
        assert _rel(ours[name], getattr(kf, PYKALMAN[name])) < SAME, name


@pytest.fixture(scope="module")
def robot():
    """pykalman's robot data (Abbeel 2011) as mptrack inputs: the observation offset subtracted from z
    (it is known, not fitted), the transition offsets as a control input B = I, u(k) = offset(k-1)
    (pykalman's offset k takes the state from time k to k+1), the masked first row as NaN."""
    d = load_robot()
    z = np.ma.filled(d.observations.astype(float), np.nan) - d.observation_offset
    u = np.zeros((z.shape[0], 5))
    u[1:] = d.transition_offsets
    start = LinearGaussianModel(d.transition_matrix, d.observation_matrix, d.initial_transition_covariance,
                                d.initial_observation_covariance)
    return d, z, u, start


def test_em_matches_pykalman_and_matlab_on_the_robot_data(robot):
    """pykalman's own check of its EM (test_kalman_fit): Q and R fitted from the data set's initial
    guesses; the log-likelihoods of the first iterations are also those the MATLAB implementation
    published with the data (pykalman/datasets/descr/robot.rst)."""
    d, z, u, start = robot
    estimate = ("Q", "R")
    fit = fit_em(start, z, x0=d.initial_state_mean, P0=d.initial_state_covariance, estimate=estimate,
                 iterations=5, tol=0, prior="first-measurement", B=np.eye(5), u=u)
    kf, loglik = _pykalman_em(start, d.observations, d.initial_state_mean, d.initial_state_covariance, estimate, 5,
                              transition_offsets=d.transition_offsets, observation_offsets=d.observation_offset)
    assert fit.iterations == 5 and not fit.converged and fit.method == "EM"
    _assert_same_fit(fit, kf, loglik, estimate)
    assert _rel(fit.loglik, d.loglikelihoods[:6]) < 1e-12       # 7e-16 measured: printed to full precision


@pytest.mark.slow
def test_em_reproduces_the_published_matlab_fit_of_the_robot_data(robot):
    """All 50 published log-likelihoods and the covariances the MATLAB EM ends at (~20 s: the controlled
    Kalman filter runs step by step in Python)."""
    d, z, u, start = robot
    fit = fit_em(start, z, x0=d.initial_state_mean, P0=d.initial_state_covariance, estimate=("Q", "R"),
                 iterations=50, tol=0, prior="first-measurement", B=np.eye(5), u=u)
    assert _rel(fit.loglik[:50], d.loglikelihoods) < 1e-12       # 9e-16 measured
    assert _rel(fit.model.Q, d.transition_covariance) < 1e-10     # 7e-14 measured
    assert _rel(fit.model.R, d.observation_covariance) < 1e-10


_TRACK_MODEL = constant_velocity(1.0, 0.5, axes=2, sigma_r2=9.0)


@pytest.fixture(scope="module")
def track():
    """A simulated 2-D constant-velocity track with 10 % of its rows missing, and a start model and
    prior that are all wrong."""
    rng = np.random.default_rng(7)
    _, z = simulate_linear(_TRACK_MODEL, 150, rng, x0=[0.0, 10.0, 0.0, -5.0])
    z[rng.random(150) < 0.1] = np.nan
    start = LinearGaussianModel(_TRACK_MODEL.F, _TRACK_MODEL.H, np.eye(4), 4.0 * np.eye(2))
    return z, start, np.array([1.0, 8.0, -1.0, -4.0]), np.diag([10.0, 5.0, 10.0, 5.0])


@pytest.mark.parametrize("prior", ["first-measurement", "initial"])
@pytest.mark.parametrize("estimate", [("Q", "R", "x0", "P0"), ("F", "H", "Q", "R", "x0", "P0")])
def test_em_matches_pykalman_on_a_simulated_track(track, prior, estimate):
    """Both priors: a prior at time 0 is pykalman's prior at a first row that is missing."""
    z, start, x0, P0 = track
    fit = fit_em(start, z, x0=x0, P0=P0, estimate=estimate, iterations=8, tol=0, prior=prior)
    zz = z if prior == "first-measurement" else np.vstack([np.full((1, 2), np.nan), z])
    kf, loglik = _pykalman_em(start, np.ma.masked_invalid(zz), x0, P0, estimate, 8)
    _assert_same_fit(fit, kf, loglik, estimate)
    if "F" not in estimate:
        np.testing.assert_array_equal(fit.model.F, start.F)


def test_em_and_direct_maximisation_reach_the_same_maximum_of_a_noise_gain_model():
    """EM of a model given as G, Qw fits Qw with G kept (Q = q G G^T): the maximum direct maximisation
    over (q, sigma_r2) finds.  Both within 1e-4 of each other, against standard errors of 20 % and 8 %."""
    make = lambda q, r: cv_discrete_white_noise(1.0, q, sigma_r2=r)  # noqa: E731
    _, z = simulate_linear(make(0.2, 4.0), 400, np.random.default_rng(3), x0=[0.0, 5.0])
    prior = dict(x0=[0.0, 5.0], P0=np.zeros((2, 2)))
    em = fit_em(make(1.0, 1.0), z, estimate=("Q", "R"), iterations=2000, tol=1e-14, **prior)
    ml = fit_ml(make, z, {"q": 1.0, "r": 1.0}, **prior)
    assert em.converged and ml.converged
    np.testing.assert_array_equal(em.model.G, make(1.0, 1.0).G)
    assert em.model.Qw[0, 0] == pytest.approx(ml.params["q"], rel=1e-4)
    assert em.model.R[0, 0] == pytest.approx(ml.params["r"], rel=1e-4)
    assert em.loglik[-1] == pytest.approx(ml.loglik[-1], abs=1e-6)
    assert ml.stderr["q"] > 0.1 * ml.params["q"]


def _two_sensors(q, r11, r22, r12):
    """A random walk seen by two sensors with correlated noise."""
    return LinearGaussianModel([[1.0]], [[1.0], [1.0]], [[q]], [[r11, r12], [r12, r22]])


def test_em_with_partly_missing_rows_reaches_the_direct_maximum():
    """Rows with one of two components missing enter EM through the missing component's distribution
    given the observed one; a wrong M-step would converge elsewhere than the likelihood's maximum."""
    rng = np.random.default_rng(5)
    _, z = simulate_linear(_two_sensors(0.5, 2.0, 1.0, 0.6), 400, rng, x0=[1.0])
    z[rng.random(z.shape) < 0.2] = np.nan
    assert (np.isnan(z).sum(axis=1) == 1).sum() > 100
    prior = dict(x0=[1.0], P0=np.zeros((1, 1)))
    em = fit_em(_two_sensors(1.0, 1.0, 1.0, 0.0), z, estimate=("Q", "R"), iterations=2000, tol=1e-14, **prior)
    ml = fit_ml(_two_sensors, z, {"q": 1.0, "r11": 1.0, "r22": 1.0, "r12": 0.0}, positive=("q", "r11", "r22"),
                **prior)
    assert em.converged and ml.converged
    fitted = [em.model.Q[0, 0], em.model.R[0, 0], em.model.R[1, 1], em.model.R[0, 1]]
    np.testing.assert_allclose(fitted, [ml.params[k] for k in ("q", "r11", "r22", "r12")], rtol=1e-4)
    assert em.loglik[-1] == pytest.approx(ml.loglik[-1], abs=1e-6)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 3), m=st.integers(1, 2),
       estimate=st.sets(st.sampled_from(["F", "H", "Q", "R", "x0", "P0"]), min_size=1),
       prior=st.sampled_from(["initial", "first-measurement"]), missing=st.sampled_from([0.0, 0.15, 0.4]))
def test_em_log_likelihood_never_decreases(seed, n, m, estimate, prior, missing):
    """Any model, data from another one, missing components: each iteration raises the likelihood (to
    rounding), and the fitted covariances are covariances."""
    rng = np.random.default_rng(seed)

    def model():
        A = rng.normal(size=(n, n))
        F = A / max(1.0, 1.05 * np.abs(np.linalg.eigvals(A)).max())
        Lq, Lr = rng.normal(size=(n, n)), rng.normal(size=(m, m))
        return LinearGaussianModel(F, rng.normal(size=(m, n)), Lq @ Lq.T + 0.1 * np.eye(n), Lr @ Lr.T + 0.1 * np.eye(m))

    _, z = simulate_linear(model(), 60, rng)
    z[rng.random(z.shape) < missing] = np.nan
    z[0, 0] = 1.0 if np.isnan(z).all() else z[0, 0]
    fit = fit_em(model(), z, x0=rng.normal(size=n), P0=np.eye(n), estimate=tuple(estimate), iterations=15, tol=0,
                 prior=prior)
    steps = np.diff(fit.loglik)
    assert np.all(steps >= -1e-9 * np.abs(fit.loglik[1:])), steps
    for cov in (fit.model.Q, fit.model.R, fit.P0):
        np.testing.assert_array_equal(cov, cov.T)
        assert np.linalg.eigvalsh(cov)[0] >= -1e-10 * np.abs(cov).max()
    assert fit.loglik[-1] == pytest.approx(kalman_filter(fit.model, z, fit.x0, fit.P0, prior=prior).loglik, rel=1e-12)


def test_em_stops_at_its_tolerance():
    z = simulate_linear(_TRACK_MODEL, 100, np.random.default_rng(2))[1]
    fit = fit_em(_TRACK_MODEL, z, P0=np.eye(4), estimate=("R",), iterations=500, tol=1e-6)
    assert fit.converged and fit.iterations < 500
    assert fit.loglik[-1] - fit.loglik[-2] <= 1e-6 * abs(fit.loglik[-1])
    assert fit_em(_TRACK_MODEL, z, P0=np.eye(4), iterations=0).iterations == 0


# ---------------------------------------------------------------- direct maximisation: recovery

def _cv(q, sigma):
    """The constant-velocity model at dt = 1 s in closed form (constant_velocity builds the same by Van
    Loan's method, tests/models pin it): a cheap model function for 100 fits."""
    return LinearGaussianModel([[1.0, 1.0], [0.0, 1.0]], [[1.0, 0.0]], q * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]]),
                               [[sigma * sigma]])


def _recovery_scores(seeds: int) -> np.ndarray:
    """(seeds, 2) errors of the fitted (q, sigma) in units of their standard errors, one simulated
    500-step track per seed (q = 0.5 m^2/s^3, sigma = 3 m, the prior known)."""
    q, sigma, x0 = 0.5, 3.0, [0.0, 10.0]
    scores = []
    for seed in range(seeds):
        _, z = simulate_linear(_cv(q, sigma), 500, np.random.default_rng(seed), x0=x0)
        fit = fit_ml(_cv, z, {"q": 1.0, "sigma": 1.0}, x0=x0, P0=np.zeros((2, 2)))
        assert fit.converged and np.all(np.diff(fit.loglik) >= 0)
        scores.append([(fit.params["q"] - q) / fit.stderr["q"], (fit.params["sigma"] - sigma) / fit.stderr["sigma"]])
    return np.array(scores)


@pytest.mark.slow
def test_ml_recovers_cv_parameters_within_their_standard_errors_over_100_seeds():
    """If the standard errors describe the error, |score| <= 1 holds for 68.3 % of the fits and <= 2
    for 95.4 %: the fractions over 100 seeds must lie within 3 binomial standard deviations (4.7 and 2.1
    points), the mean score within 3 / sqrt(100) of 0."""
    scores = _recovery_scores(100)
    within1, within2 = (np.abs(scores) <= 1).mean(axis=0), (np.abs(scores) <= 2).mean(axis=0)
    assert np.all(np.abs(within1 - 0.683) <= 3 * 0.047), within1
    assert np.all(np.abs(within2 - 0.954) <= 3 * 0.021), within2
    assert np.all(np.abs(scores.mean(axis=0)) <= 0.3), scores.mean(axis=0)


def test_ml_recovers_cv_parameters_within_their_standard_errors():
    """The default suite's version of the 100-seed check, on 20 seeds (bounds of 3 binomial sd)."""
    scores = _recovery_scores(20)
    within1, within2 = (np.abs(scores) <= 1).mean(axis=0), (np.abs(scores) <= 2).mean(axis=0)
    assert np.all(np.abs(within1 - 0.683) <= 3 * 0.104), within1
    assert np.all(within2 >= 0.954 - 3 * 0.047), within2
    assert np.all(np.abs(scores.mean(axis=0)) <= 3 / np.sqrt(20)), scores.mean(axis=0)


def test_ml_of_a_parameter_of_any_sign():
    """positive=() fits on the natural scale: an AR(1) coefficient of either sign."""
    ar = lambda phi, r: LinearGaussianModel([[phi]], [[1.0]], [[1.0]], [[r]])  # noqa: E731
    for phi in (-0.7, 0.7):
        _, z = simulate_linear(ar(phi, 0.5), 800, np.random.default_rng(11))
        fit = fit_ml(ar, z, {"phi": 0.0, "r": 1.0}, positive=("r",), P0=[[1.0]])
        assert abs(fit.params["phi"] - phi) < 3 * fit.stderr["phi"]
        assert fit.stderr["phi"] < 0.1
        assert isinstance(fit, FitResult) and fit.model.F[0, 0] == fit.params["phi"]


def test_ml_refuses_a_parameter_the_data_do_not_determine():
    """A parameter the likelihood does not depend on has no standard error: refused, naming it."""
    make = lambda q, sigma, unused: _cv(q, sigma)  # noqa: E731
    _, z = simulate_linear(_cv(0.5, 3.0), 200, np.random.default_rng(1))
    with pytest.raises(ParameterError, match="^params: the data do not determine unused:"):
        fit_ml(make, z, {"q": 1.0, "sigma": 1.0, "unused": 1.0}, P0=np.eye(2))


# ---------------------------------------------------------------- bad input

def test_em_errors_name_the_argument():
    z = simulate_linear(_TRACK_MODEL, 20, np.random.default_rng(0))[1]
    P0 = np.eye(4)
    for kwargs, start in [(dict(estimate=("Q", "K")), "estimate"), (dict(estimate=()), "estimate"),
                          (dict(estimate=3), "estimate"), (dict(iterations=-1), "iterations"),
                          (dict(tol=-1.0), "tol"), (dict(prior="later"), "prior")]:
        with pytest.raises(ParameterError, match=f"^{start}:"):
            fit_em(_TRACK_MODEL, z, P0=P0, **kwargs)
    with pytest.raises(NonFiniteError, match="^tol:"):
        fit_em(_TRACK_MODEL, z, P0=P0, tol=np.inf)
    with pytest.raises(ParameterError, match="^P0:"):
        fit_em(_TRACK_MODEL, z, P0=None)
    with pytest.raises(ParameterError, match="^z: no measurement"):
        fit_em(_TRACK_MODEL, np.full((5, 2), np.nan), P0=P0)
    with pytest.raises(ParameterError, match="^z: fitting Q needs a transition"):
        fit_em(_TRACK_MODEL, z[:1], P0=P0, prior="first-measurement")
    with pytest.raises(ShapeError, match="^z:"):
        fit_em(_TRACK_MODEL, z[:, :1], P0=P0)
    with pytest.raises(ParameterError, match="^model:"):
        fit_em("model", z, P0=P0)
    gain = LinearGaussianModel.from_noise_gain(np.eye(2), [[1.0, 0.0]], [[1.0, 1.0], [1.0, 1.0]], np.eye(2), [[1.0]])
    with pytest.raises(ParameterError, match="^model: its noise gain G"):
        fit_em(gain, z[:, :1], P0=np.eye(2))


def test_em_refuses_a_singular_fitted_noise():
    """Two sensors that always agree: the fitted R is singular (no noise in their difference) and is
    refused, naming z."""
    model = _two_sensors(1.0, 1.0, 1.0, 0.0)
    z = np.repeat(np.cumsum(np.random.default_rng(0).normal(size=(30, 1)), axis=0), 2, axis=1)
    with pytest.raises(NotPositiveDefiniteError, match="^z: the EM estimate"):
        fit_em(model, z, x0=[0.0], P0=np.zeros((1, 1)), estimate=("R",), iterations=5, tol=0)


def test_ml_errors_name_the_argument():
    z = simulate_linear(_cv(0.5, 3.0), 20, np.random.default_rng(0))[1]
    P0 = np.eye(2)
    cases = [(dict(model=_TRACK_MODEL), "model"), (dict(model=lambda q, sigma: 3), "model"),
             (dict(params={}), "params"), (dict(params={"q": -1.0, "sigma": 1.0}), "params"),
             (dict(params={"q": np.nan, "sigma": 1.0}), "params"), (dict(params={"q": "a", "sigma": 1.0}), "params"),
             (dict(params=[1.0, 2.0]), "params"), (dict(params={"q": 1.0}), "params"),
             (dict(positive=("q", "s")), "positive"), (dict(iterations=1.5), "iterations"),
             (dict(model=lambda q, sigma: _cv(-q, sigma)), "params")]
    for kwargs, start in cases:
        args = dict(model=_cv, params={"q": 1.0, "sigma": 1.0}, positive=None, iterations=50) | kwargs
        with pytest.raises(ParameterError, match=f"^{start}:"):
            fit_ml(args["model"], z, args["params"], P0=P0, positive=args["positive"], iterations=args["iterations"])
    with pytest.raises(ParameterError, match="^P0:"):
        fit_ml(_cv, z, {"q": 1.0, "sigma": 1.0}, P0=None)


@pytest.mark.parametrize("scale", [1e-150, 1e-100, 1e100, 1e150])
def test_fits_do_not_depend_on_the_units(scale):
    """Measurements and noise at the edges of the float range (metres -> 1e150 m): the same fit as in
    metres, the log-likelihood shifted by T ln(scale) (the density's units)."""
    z = simulate_linear(_cv(0.5, 3.0), 60, np.random.default_rng(4))[1]
    fits = []
    for s in (1.0, scale):
        em = fit_em(_cv(s**2, s), z * s, P0=s**2 * np.eye(2), iterations=5)
        ml = fit_ml(lambda q, sigma: _cv(q * s**2, sigma * s), z * s, {"q": 1.0, "sigma": 1.0}, P0=s**2 * np.eye(2))
        fits.append((em.model.Q / s**2, em.model.R / s**2, em.loglik + 60 * np.log(s), ml.params["q"],
                     ml.params["sigma"], ml.loglik[-1] + 60 * np.log(s)))
    for a, b in zip(*fits):
        np.testing.assert_allclose(b, a, rtol=1e-5)
