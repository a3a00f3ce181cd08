"""Issue 16: every public function gives a finite answer or a clear mptrack error.

Property tests over the harness of ``tests/_hardening.py``, which has an argument strategy for every
callable in the ``__all__`` of every public package (the first test fails when one is missing): for
generated arguments of every kind (arrays of any shape, dtype and magnitude with NaN/Inf sprinkled,
ragged lists, wrong types, huge sizes, names, files, tables) each public function returns a finite
result (NaN only where the input had NaN = missing) or raises an ``mptrack.errors`` exception whose
message STARTS with an argument the caller passed, within a time bound (10 s, every numba kernel
signature compiled first) and an allocation bound (512 MiB, traced).
A small run is in the default suite; ``-m slow`` runs >= 10,000 examples.
"""

from __future__ import annotations

import math
import time

import _hardening as H
import numpy as np
import pytest
import scipy.linalg
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mptrack import batch, linear, riccati, runs, tracking
from mptrack.errors import (
    ConvergenceError,
    MptrackError,
    NonFiniteError,
    NotPositiveDefiniteError,
    ParameterError,
    ResourceError,
    ShapeError,
    SingularMatrixError,
)
from mptrack.models import LinearGaussianModel, assimakis_model_b

B = assimakis_model_b()


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    H.warm_up()


def test_every_public_function_has_a_strategy():
    """Each callable of each public package's ``__all__`` is a target or a listed result record, and
    every target is public: a new public function fails here until the harness covers it."""
    public = H.public_callables()
    missing = sorted(set(public) - set(H.TARGETS) - H.RECORDS)
    assert not missing, f"public functions without a strategy in tests/_hardening.py: {missing}"
    # "package.name", "package.Class.method" or "package.name[variant]" (a second set of strategies)
    stale = sorted(name for name in H.TARGETS if ".".join(name.split("[")[0].split(".")[:2]) not in public)
    assert not stale and H.RECORDS <= set(public), (stale, sorted(H.RECORDS - set(public)))
    assert set(H.PACKAGES) >= {"mptrack", "linear", "batch", "riccati", "models", "nonlinear", "cellular",
                               "continuous", "radio", "fuzzy", "metrics", "burden", "sim", "tracking", "io"}


def test_packages_are_found_not_listed():
    """Every public module is fuzzed unless excluded with a reason: the packages are found on disk, so a
    new package is in the harness as soon as it exists (and the test above fails until it has strategies)."""
    modules = set(H.public_modules())
    assert set(H.NOT_FUZZED) <= modules, sorted(set(H.NOT_FUZZED) - modules)
    assert set(H.PACKAGES) == (modules - set(H.NOT_FUZZED)) | {"mptrack"}
    for package in H.PACKAGES:
        module = H._module(package)
        assert isinstance(getattr(module, "__all__", None), list), f"mptrack.{package} has no __all__"


def test_messages_must_start_with_an_argument():
    """The classification is strict: naming an argument later in the message is not enough."""
    assert H.starts_with_argument("x0: too large", ("x0",))
    assert H.starts_with_argument("model.F: singular", ("model",))
    assert not H.starts_with_argument("EKF: singular; check R and P0", ("R", "P0"))
    assert not H.starts_with_argument("|innovation|: contains inf", ("z",))


def test_compilation_does_not_count_against_the_time_bound():
    """A kernel signature compiled inside the timed call (a cold numba cache, a model size or dtype no
    warm-up reached) is not a hang: the bound counts the call's own work.  It used to count the
    compilation, and batch.kalman_filter was reported as a hang on a cold cache."""
    import numba

    def compiles_in_the_call():
        @numba.njit   # not cached: compiled inside the timed call, for longer than the bound
        def kernel(x):
            s = 0.0
            for i in range(x.shape[0]):
                s += np.sin(x[i]) * np.cos(x[i])
            return s
        return kernel(np.ones(3))

    outcome, detail = H.classify(compiles_in_the_call, {}, (), time_bound=0.01)
    assert outcome == "ok", detail
    # the call's own work past the bound is still a hang
    assert H.classify(lambda: time.sleep(1.0), {}, (), time_bound=0.05)[0] == "hang"


def _check(name, data):
    kwargs = data.draw(H.TARGETS[name].strategy, label="arguments")
    outcome, detail = H.run_target(name, kwargs)
    assert outcome in H.GOOD, f"{name}: {outcome} {detail}"


#: the large run: at least 10,000 generated calls over all targets
_LARGE_EXAMPLES = math.ceil(10_000 / len(H.TARGETS)) + 1
_SMALL = settings(max_examples=6, deadline=None, derandomize=True, database=None,
                  suppress_health_check=list(HealthCheck))
_LARGE = settings(max_examples=_LARGE_EXAMPLES, deadline=None, derandomize=True, database=None,
                  suppress_health_check=list(HealthCheck))


@pytest.mark.parametrize("name", list(H.TARGETS))
@_SMALL
@given(data=st.data())
def test_finite_answer_or_clean_error(name, data):
    _check(name, data)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(H.TARGETS))
@_LARGE
@given(data=st.data())
def test_finite_answer_or_clean_error_large(name, data):
    """Over 10,000 examples in all."""
    _check(name, data)


def test_large_run_has_at_least_10000_examples():
    assert _LARGE.max_examples * len(H.TARGETS) >= 10_000


@pytest.mark.parametrize("case", H.CORPUS, ids=[f"class{c[0]}-{c[1]}" for c in H.CORPUS])
def test_issue_examples(case):
    """One example of each failure class found by the fuzz run of issue 16 and by its audit."""
    cls, label, call, params = case
    outcome, detail = H.classify(lambda: call(), {}, params)
    assert outcome in H.GOOD, f"class {cls} {label}: {outcome} {detail}"


# --- the output-finiteness policy: an overflow names the input that caused it ------------------

def test_overflow_in_a_filter_names_the_large_input():
    with pytest.raises(NonFiniteError, match=r"^x0: the Kalman filter overflowed"):
        linear.kalman_filter(B, np.zeros((3, 1)), x0=[1e308, 1e308], P0=np.zeros((2, 2)))


def test_overflow_of_a_derived_quantity_names_its_inputs():
    with pytest.raises(NonFiniteError, match=r"^G: Q = G Qw G\^T overflowed"):
        LinearGaussianModel(np.eye(2), np.eye(2), None, np.eye(2), G=[[1e200, 0], [0, 1]], Qw=np.eye(2))
    with pytest.raises(NonFiniteError, match=r"^dt: Q = sigma_a2 G G\^T overflowed"):
        batch.RangeModel.constant_velocity(1e300, 1.0, H.STATIONS, 1.0)


def test_batch_engine_refuses_infinity_but_keeps_nan_as_missing():
    z = np.ones((2, 4, 1))
    z[1, 2, 0] = np.nan
    x = batch.steady_state_filter(B, z).x
    assert np.isfinite(x).all()
    z[0, 1, 0] = np.inf
    with pytest.raises(NonFiniteError, match=r"^z: contains infinite value"):
        batch.steady_state_filter(B, z)


def test_range_ekf_prior_on_a_station_is_finite():
    """The Jacobian at a station is undefined; the range is floored as in ekf_ranges."""
    z = np.full((1, 3, 3), 500.0)
    x = batch.ekf_ranges(H.RANGE_MODEL, z, [0.0, 0.0, 0.0, 0.0], np.eye(4) * 100.0).x
    assert np.isfinite(x).all()


# --- Riccati: the wrong refusal and the stopping rule -------------------------------------------

def test_undriven_mode_outside_the_unit_circle_is_solved_like_scipy():
    model = LinearGaussianModel([[2.0]], [[1.0]], [[0.0]], [[1.0]])
    for method in riccati.METHODS:
        assert riccati.steady_state(model, method).P_pred[0, 0] == pytest.approx(3.0, rel=1e-12)
    # and the Kalman filter from P0 > 0 converges to the same P
    kf = linear.kalman_filter(model, np.zeros((60, 1)), P0=[[1.0]])
    assert kf.P_pred[-1, 0, 0] == pytest.approx(3.0, rel=1e-12)


def _dare_residual(A, Bc, Q, R, X) -> float:
    """scipy's residual of the control DARE (its test_solvers check)."""
    return float(np.abs(A.T @ X @ A - X + Q - A.T @ X @ Bc @ np.linalg.solve(R + Bc.T @ X @ Bc, Bc.T @ X @ A)).max())


@pytest.mark.parametrize("solve", [
    lambda m: riccati.steady_state(m, "per-step"),
    lambda m: riccati.steady_state(m, "doubling"),
    lambda m: riccati.steady_state(m, "per-step", form="lainiotis"),
], ids=["per-step", "doubling", "relf"])
def test_default_stopping_rule_meets_scipys_residual_bar(solve):
    """On each of scipy's real DARE test cases the default stopping rule leaves a residual within
    10x that of scipy's own solution (tol=1e-13, the old rule, missed it on 8 of them)."""
    from _dare_cases import DAREX, darex_model
    for key, mats in DAREX.items():
        A, Bc, Q, R = (np.asarray(M, dtype=float) for M in mats)
        X = scipy.linalg.solve_discrete_are(A, Bc, Q, R)
        ours = _dare_residual(A, Bc, Q, R, solve(darex_model(key)).P_pred)
        assert ours <= 10 * _dare_residual(A, Bc, Q, R, X) + 1e-15, key


def test_old_stopping_rule_missed_the_bar():
    """The test above can fail: the relative step 1e-13 leaves larger residuals."""
    from _dare_cases import DAREX, darex_model
    missed = 0
    for key, mats in DAREX.items():
        A, Bc, Q, R = (np.asarray(M, dtype=float) for M in mats)
        X = scipy.linalg.solve_discrete_are(A, Bc, Q, R)
        P = riccati.steady_state(darex_model(key), "per-step", tol=1e-13).P_pred
        missed += _dare_residual(A, Bc, Q, R, P) > 10 * _dare_residual(A, Bc, Q, R, X) + 1e-15
    assert missed >= 5


def test_steady_state_time_keeps_its_definition():
    ss = riccati.steady_state(B, "per-step")
    assert ss.steady_state_time == riccati.steady_state(B, "per-step", tol=1e-13).steady_state_time
    assert ss.iterations >= ss.steady_state_time


# --- resources: closed forms, lazy chunks, estimated allocations ---------------------------------

def test_prediction_covariance_of_a_huge_horizon_is_a_closed_form():
    start = time.perf_counter()
    P = linear.prediction_covariance(LinearGaussianModel([[0.5]], [[1.0]], [[1.0]], [[1.0]]), [[2.0]], 10**12)
    assert time.perf_counter() - start < 0.5
    assert P[0, 0] == pytest.approx(1.0 / (1.0 - 0.25), rel=1e-14)     # the Lyapunov limit
    # and it equals the step-by-step recursion for small N
    P_step = np.eye(2)
    for N in range(1, 6):
        P_step = B.F @ P_step @ B.F.T + B.Q
        np.testing.assert_allclose(linear.prediction_covariance(B, np.eye(2), N), P_step, rtol=1e-13)


def test_prediction_of_an_unstable_model_far_ahead_overflows_cleanly():
    model = LinearGaussianModel([[2.0]], [[1.0]], [[1.0]], [[1.0]])
    with pytest.raises(NonFiniteError, match=r"^N: the N-step prediction (covariance )?overflowed"):
        linear.predict_ahead(model, linear.kalman_filter(model, np.ones((3, 1)), P0=[[0.0]]), 10**12)
    # a marginally stable model is fine that far ahead (F^N = [[1, N], [0, 1]])
    assert np.isfinite(linear.predict_ahead(B, linear.kalman_filter(B, np.ones((3, 1)), P0=np.zeros((2, 2))), 10**12).P).all()


def test_make_chunks_is_lazy():
    chunks = runs.make_chunks(10**12, 3, seed=1)
    assert len(chunks) == (10**12 + 2) // 3
    last = chunks[-1]
    assert (last.start, last.stop, last.index) == (10**12 - 1, 10**12, len(chunks) - 1)
    assert [(c.index, c.start, c.stop) for c in runs.make_chunks(7, 3)] == [(0, 0, 3), (1, 3, 6), (2, 6, 7)]
    assert [c.stop for c in runs.make_chunks(7, 3)[1:]] == [6, 7]


@pytest.mark.parametrize("call, name", [
    (lambda: batch.monte_carlo(B, 5, 10**12, seed=1), "runs"),
    (lambda: batch.gain_sequence(B, 10**12), "steps"),
    (lambda: __import__("mptrack.sim").sim.simulate_linear(B, 10**12, np.random.default_rng(0)), "steps"),
])
def test_huge_sizes_are_refused_before_allocating(call, name):
    with pytest.raises(ResourceError, match=rf"^{name}: .* needs .* of memory"):
        call()


def test_memory_limit_can_be_set(monkeypatch):
    monkeypatch.setenv("MPTRACK_MAX_BYTES", "1e6")
    with pytest.raises(ResourceError, match=r"limit of 977 KiB"):
        batch.gain_sequence(B, 10**5)


# --- messages name what the caller passed --------------------------------------------------------

@pytest.mark.parametrize("call, name", [
    (lambda: linear.kalman_filter(B, [[1.0], [2.0, 3.0]]), "z"),
    (lambda: batch.kalman_filter(B, np.ones((1, 2, 1)), x0=[[1.0], [2.0, 3.0]]), "x0"),
    (lambda: linear.per_axis(linear.kalman_filter, None, np.ones((3, 2))), "axis_model"),
    (lambda: riccati.riccati_step(B, np.eye(3)), "P_pred"),
    (lambda: linear.prediction_covariance(B, np.eye(2), 2.0), "N"),
    (lambda: riccati.check_detectable(np.full((2, 2), np.nan), np.eye(2)), "F"),
])
def test_messages_name_the_argument(call, name):
    with pytest.raises((ShapeError, ParameterError, NonFiniteError, TypeError), match=rf"^{name}\b"):
        call()


@pytest.mark.parametrize("kwargs, name", [(dict(sigma_m=1e-300), "sigma_m"), (dict(q=1e308), "q")])
def test_tracking_options_name_the_given_noise_not_a_derived_one(kwargs, name):
    """--sigma 1e-300 used to fail later as "sigma_r2 ... got 0.0" (its square), --q 1e308 as
    "dt: 0.0 s is too long"; the options now refuse them under the names given."""
    from mptrack.tracking import TrackOptions
    with pytest.raises(ParameterError, match=rf"^{name}: expected values in"):
        TrackOptions(**kwargs)


def test_a_per_step_recursion_lost_in_rounding_stops_early_and_names_the_method():
    """F with entries ~10^3 observed in one component: float64 rounding makes the per-step
    recursion wander (relative steps up to 1e9 after 1000 iterations); it stops at the first check
    instead of running 10^5 iterations, and says which method to use."""
    F = np.array([[477.12454, -845.3525, -929.82336], [1061.1157, -202.70943, 1307.7375],
                  [1381.299, 1404.6664, -1727.3438]])
    model = LinearGaussianModel(F, [[1.0, 0.0, 0.0]], 1e-3 * np.eye(3), [[71797683.04221904]])
    with pytest.raises(ConvergenceError, match=r"^method: the per-step Riccati recursion is not converging .* "
                                               r"use method='dare'"):
        riccati.steady_state(model, "per-step")
    assert np.isfinite(riccati.steady_state(model, "dare").P_pred).all()


# --- the audit of the first fix: the classes it found ---------------------------------------------

def test_size_is_checked_before_the_values_are_scanned():
    """A broadcast view of 10^12 rows used to be scanned value by value for minutes."""
    start = time.perf_counter()
    with pytest.raises(ResourceError, match=r"^F: an array of shape \(1000000000000, 2\) needs"):
        linear.kalman_step(np.broadcast_to(1.0, (10**12, 2)), B.H, B.Q, B.R, np.zeros(2), np.eye(2), np.ones(1))
    with pytest.raises(ResourceError, match=r"^z: "):
        linear.kalman_filter(B, np.broadcast_to(1.0, (10**12, 1)), P0=np.eye(2))
    assert time.perf_counter() - start < 1.0


def test_fir_order_beyond_the_data_costs_nothing():
    """The FIR window never reaches further back than the T steps: M = 10^12 is M = T."""
    z = np.random.default_rng(3).normal(size=(6, 1))
    np.testing.assert_array_equal(linear.fir_filter(B, z, M=10**12).x, linear.fir_filter(B, z, M=6).x)
    zb = z[None].repeat(2, axis=0)
    np.testing.assert_array_equal(batch.fir_filter(B, zb, M=10**12).x, batch.fir_filter(B, zb, M=6).x)
    with pytest.raises(ResourceError, match=r"^M: 1000000000000 needs"):
        linear.fir_coefficients(0.5 * np.eye(2), np.ones((2, 1)), 10**12)


def test_ranges_of_huge_coordinates_are_finite():
    """hypot instead of the square root of a sum of squares: no overflow below the float range."""
    r, H_ = __import__("mptrack.cellular").cellular.range_measurement(np.array([1e300, 0.0]), H.STATIONS)
    np.testing.assert_allclose(r, 1e300)
    assert np.isfinite(H_).all()


def test_a_singular_innovation_covariance_is_not_an_overflow():
    """R = 1e-30 on exact ranges: the innovation covariance is singular; the error says so and names R
    (it said "overflowed the float64 range" and named stations, the largest input)."""
    from mptrack import cellular
    with pytest.raises(SingularMatrixError, match=r"^R: .*a matrix the EKF inverts became singular"):
        cellular.ekf_ranges_batch(np.full((1, 3, 3), 500.0), H.STATIONS, [[1.0, 1.0]], np.eye(2), np.eye(2), 1e-30)


@pytest.mark.parametrize("q, sigma", [(1e-3, 1e7), (1.0, 1e9), (1e-6, 1e20), (1e80, 5.0)])
def test_dare_solves_badly_scaled_problems(q, sigma):
    """scipy's QZ method failed on these solvable problems (the PBH tests pass); the scaled problem, or
    the doubling algorithm where QZ still fails, solves them (to the doubling answer's precision)."""
    from mptrack.models import constant_velocity_continuous
    model = constant_velocity_continuous(q, axes=1, sigma_r2=sigma ** 2).discretize(1.0)
    P = riccati.steady_state(model, "dare").P_pred
    np.testing.assert_allclose(P, riccati.steady_state(model, "doubling").P_pred, rtol=1e-6)
    assert riccati.riccati_residual(model, P) < 1e-6


def test_tracking_sigma_bound_is_where_the_engine_stays_finite():
    """--sigma 1e140 passed the old bound (1e150) and failed in the engine as "east: non-finite"."""
    from mptrack.tracking import TrackOptions
    with pytest.raises(ParameterError, match=r"^sigma_m: expected values in \[1e-150, 1e\+70\] m"):
        TrackOptions(sigma_m=1e140)
    assert TrackOptions(sigma_m=1e70).sigma_m == 1e70


@pytest.mark.parametrize("call, name", [
    (lambda: __import__("mptrack.models").models.cv_discrete_white_noise(1e300, 1.0), "dt"),
    (lambda: __import__("mptrack.models").models.range_bearing(np.array([np.inf, 0.0]), np.diag([25.0, 1e-4])),
     "sensor"),
    (lambda: riccati.check_detectable(np.array([[1e300, 0], [0, 1.0]]), np.array([[0.0, 1.0]])), "F"),
    (lambda: __import__("mptrack.fuzzy").fuzzy.triangular(np.ones(2), 0, 0.5, np.inf), "c"),
    (lambda: __import__("mptrack.metrics").metrics.pcrb_ranges(np.array([[np.inf, 400.0], [310.0, 400.0]]),
                                                                H.STATIONS, np.eye(2), np.eye(2), 25.0), "truth"),
])
def test_derived_and_passed_on_arguments_are_named_as_given(call, name):
    with pytest.raises(Exception, match=rf"^{name}:"):
        call()


# --- the audit's fuzz re-run after the merge with main: what it still found -----------------------

def test_memory_limit_respects_the_address_space_limit(monkeypatch):
    """Under ``ulimit -v`` (6 GiB in the audit's runner) an allocation the physical-memory limit let
    through (gain_sequence of 10^8 steps, 8 GB) died as a MemoryError; the limit is now at most half
    the address-space limit, so it is refused first, by name."""
    import resource

    from mptrack._core.validation import memory_limit
    monkeypatch.delenv("MPTRACK_MAX_BYTES", raising=False)
    monkeypatch.setattr(resource, "getrlimit", lambda what: (6 * 2**30, resource.RLIM_INFINITY))
    assert memory_limit() <= 3 * 2**30
    with pytest.raises(ResourceError, match=r"^steps: 100000000 needs"):
        batch.gain_sequence(B, 10**8)


def test_a_relabelled_error_is_not_relabelled_again():
    """cellular.ekf_ranges runs the generic EKF: its error was named twice ("stations: model: EKF: ...",
    the largest input of each layer); a covariance that loses definiteness in a run comes from a scale
    too small for the others, so the smallest input is named, once."""
    from mptrack import cellular
    with pytest.raises(NotPositiveDefiniteError, match=r"^R: EKF: the innovation covariance at measurement 0"):
        cellular.ekf_ranges(np.full((3, 3), 500.0), H.STATIONS, [1.0, 1.0], np.eye(2), np.eye(2), 1e-30)


def test_an_unpassed_parameter_is_a_name_of_the_call():
    """A message about a parameter left out (P0 is required) starts with it; it used to be renamed
    after the largest given input ("x0: P0: the prior covariance is required")."""
    with pytest.raises(ParameterError, match=r"^P0: the prior covariance is required"):
        linear.kalman_filter(B, np.zeros((3, 1)), x0=[1e308, 1e308])


@pytest.mark.parametrize("call, name", [
    (lambda: batch.ekf_ranges(batch.RangeModel.constant_velocity(1.0, 1.0, H.STATIONS, 1e-300),
                             np.full((1, 3, 3), 500.0), [1.0, 0.0, 1.0, 0.0], np.eye(4)), "model"),
    (lambda: __import__("mptrack.metrics").metrics.nees(np.ones((2, 2)), np.array([np.eye(2) * 1e-320] * 2),
                                                         np.zeros((2, 2))), "P"),
])
def test_a_negligible_scale_is_not_reported_as_an_overflow(call, name):
    """NaN from moderate inputs of which one is negligible (sigma_r2 = 1e-300; P = 1e-320), and numba's
    SystemError around a ZeroDivisionError, were "overflowed the float64 range" naming the largest input."""
    with pytest.raises(SingularMatrixError, match=rf"^{name}: a matrix .* inverts became singular"):
        call()


def test_exact_ranges_with_a_negligible_noise_give_the_position():
    """Three exact ranges with sigma_r2 = 1e-30: S = H P H^T + R is singular but for R.  The update
    through inv(S) broke down (a SingularMatrixError naming the model); the shared Kalman core solves
    with a Cholesky factor, which holds here, and returns the exact position."""
    truth = np.array([300.0, 400.0])
    z = np.linalg.norm(np.array([truth] * 3)[:, None] - H.STATIONS, axis=-1)[None]
    res = batch.ekf_ranges(batch.RangeModel.constant_velocity(1.0, 1.0, H.STATIONS, 1e-30), z,
                          [300.0, 0.0, 400.0, 0.0], np.eye(4))
    np.testing.assert_allclose(res.x[0][:, [0, 2]], np.tile(truth, (3, 1)), rtol=0, atol=1e-9)


def test_fir_order_of_a_slowly_decaying_matrix_is_immediate():
    """||A^M|| >= rho^M: the scan starts where rho^M falls below eps (A^M by repeated squaring), not at
    M = 1 (rho = 0.999999, eps = 1e-12: 2.8e7 products, over a minute)."""
    start = time.perf_counter()
    assert linear.fir_order(0.999999 * np.eye(2), 1e-12, max_order=10**12) == 27631008
    with pytest.raises(ConvergenceError, match=r"^max_order: .* more than max_order = 100000"):
        linear.fir_order(0.999999 * np.eye(2), 1e-12)
    assert time.perf_counter() - start < 1.0


def test_fir_order_is_the_smallest_order():
    """The same M as the scan from 1, on random stable matrices, normal and not."""
    def scan(A, eps, norm):
        power = A.copy()
        for M in range(1, 100_000):
            if np.linalg.norm(power, norm) < eps:
                return M
            power = power @ A
    rng = np.random.default_rng(16)
    for _ in range(200):
        A = rng.normal(size=(3, 3))
        A *= rng.uniform(0.05, 0.995) / max(abs(np.linalg.eigvals(A)))
        eps, norm = 10.0 ** rng.uniform(-12, -1), [2, 1, np.inf, "fro"][rng.integers(4)]
        assert linear.fir_order(A, eps, norm=norm) == scan(A, eps, norm)


def test_a_per_step_recursion_too_slow_to_finish_stops_with_advice():
    """A mode of F at 0.999999 barely driven: the per-step recursion needs ~10^7 steps (minutes) even
    with max_iter = 10^12; it stops from its measured rate and points to the doubling algorithm."""
    model = LinearGaussianModel(np.eye(2) * 0.999999, [[1.0, 0.0]], np.eye(2) * 1e-12, [[1.0]])
    start = time.perf_counter()
    with pytest.raises(ConvergenceError, match=r"^method: the per-step Riccati recursion converges by a factor"):
        riccati.steady_state(model, "per-step", max_iter=10**12)
    with pytest.raises(ConvergenceError, match=r"^max_iter: .* more than max_iter = 100000; use method='doubling'"):
        riccati.steady_state(model, "per-step")
    assert time.perf_counter() - start < 30.0
    P = riccati.steady_state(model, "doubling").P_pred
    assert riccati.riccati_residual(model, P) < 1e-12


def test_a_measurement_reading_beyond_the_state_is_refused():
    """Since the named measurements index the state with slices (fast views), an index beyond the
    motion's state was cut off silently: ranges at position=(0, 2) on a 2-state motion computed ranges
    from x[0] alone (h) and failed in numpy (its Jacobian).  The constructors record the states they read."""
    from mptrack import models
    for measurement in (models.ranges(H.STATIONS, 25.0), models.range_rate([0.0, 0.0], 1.0),
                        models.stack_measurements(models.position(np.eye(2)), models.bearings(H.STATIONS, 1e-4))):
        with pytest.raises(ShapeError, match=r"^measurement: reads state component [23] .* motion has n = 2"):
            models.nonlinear_model(B, measurement)
    assert models.nonlinear_model(models.constant_velocity(1.0, 0.1, 2), models.ranges(H.STATIONS, 25.0)).n == 4


# --- the large run after the second merge: its failures, one example each -------------------------

def _simulate_q(q):
    from mptrack.tracking import simulate
    return simulate("gps", 1, np.random.default_rng(0), duration_s=2.0, q=q, speed_mps=0.0)


def _object_column(frame, column, row, value):
    frame = frame.copy()
    frame[column] = frame[column].astype(object)
    frame.iloc[row, frame.columns.get_loc(column)] = value
    return frame


@pytest.mark.parametrize("call, error, message", [
    (lambda: __import__("mptrack.models").models.tdoa(H.STATIONS, [[1.0], [2.0, 3.0]]), Exception, r"^R: cannot"),
    (lambda: __import__("mptrack.cellular").cellular.check_stations(H.STATIONS, min_count="3"), ParameterError,
     r"^min_count: expected an integer"),
    (lambda: __import__("mptrack.continuous").continuous.pf_substep_study(
        H.ZHAO, [[1.0], [2.0, 3.0]], [0.0, 0.0], np.eye(2)), Exception, r"^z: cannot"),
    (lambda: __import__("mptrack.radio").radio.wi_free_space_loss([0.1, 1.0], 900.0, constant_db=None),
     ParameterError, r"^constant_db: expected a real number"),
    (lambda: __import__("mptrack.radio").radio.cost231_wi_los(np.array([0.1, 1.0, 2.0]), np.array([900.0, 1800.0]),
                                                             on_invalid="ignore"), ShapeError, r"^frequency_mhz:"),
    (lambda: _simulate_q(1e30), ParameterError, r"^q: east, north: the point"),
    (lambda: __import__("mptrack.tracking").tracking.evaluate_tracks(H.POINTS_WITH_TRUTH, truth_columns="yes"),
     ParameterError, r"^truth_columns: expected True or False"),
    (lambda: __import__("mptrack.tracking").tracking.evaluate_tracks(
        _object_column(H.POINTS_WITH_TRUTH, "true_lon", 1, np.inf), truth_columns=True),
     NonFiniteError, r"^tracks\.true_lon: contains infinite value"),
    (lambda: __import__("mptrack.tracking").tracking.kalman_filter_gated(
        H.CV2, [3e-31, 1e-30, 1e200], np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]), np.zeros(4), np.eye(4)),
     NonFiniteError, r"^times: the discretisation"),
    (lambda: __import__("mptrack.tracking").tracking.track_fixes(H.TRACK_ID, H.ROWS, q=1e308), NonFiniteError,
     r"^q: the discretisation"),
    # a 1e300 s gap starts a new segment by default (nothing to discretise); bridged, its discretisation overflows
    (lambda: __import__("mptrack.tracking").tracking.track_fixes(
        H.TRACK_ID, _object_column(H.ROWS, "t", 0, -1e300), __import__("mptrack.tracking").tracking.TrackOptions(
            max_gap_s=None)), NonFiniteError, r"^rows: the discretisation"),
])
def test_large_run_findings_are_named_errors(call, error, message):
    """Each raised a NumPy/numba error, named a derived quantity (R, lon, model, times), or accepted
    garbage ("yes" as a flag, +-Inf in a truth column), before."""
    with pytest.raises(error, match=message):
        call()


def test_a_covariance_near_the_float_maximum_is_symmetrised_without_overflow():
    """0.5 (R + R^T) overflowed to inf for entries beyond 9e307: position(R=1e308) returned R = inf."""
    from mptrack import models
    assert np.isfinite(models.position(1e308).R).all()


def test_duplicate_stations_are_found_by_sorting():
    """The pairwise distances took m^2 memory (20,000 stations: 6 GB); -0.0 and 0.0 are one position."""
    from mptrack.cellular import check_stations
    many = np.column_stack([np.arange(20_000.0), np.zeros(20_000)])
    assert check_stations(many).shape == (20_000, 2)
    with pytest.raises(ParameterError, match=r"^stations: stations 0 and 2 are at the same position"):
        check_stations([[0.0, 0.0], [1.0, 0.0], [-0.0, 0.0]])


# --- issue 35: the last fuzz findings' siblings ------------------------------------------------------
# Each finding was a computation that worked in the units of the tests (metres, variances near 1) and
# broke at other scales: an absolute floor, a rank tolerance or a norm that squares.  The siblings are
# checked as properties over 600 orders of magnitude: the same answer in any units, or a clear error.

_SCALES = st.integers(-200, 140).map(lambda e: 10.0 ** e)


@settings(max_examples=40, deadline=None)
@given(scale=_SCALES, offset=st.sampled_from([0.0, 1e6]), seed=st.integers(0, 2**32 - 1))
def test_range_fix_does_not_depend_on_the_units(scale, offset, seed):
    """Stations and handset in any unit (1e-200 .. 1e140 m) and far from the origin: the same fix."""
    from mptrack import cellular
    rng = np.random.default_rng(seed)
    stations = rng.uniform(0.0, 1000.0, size=(4, 2)) + offset
    truth = rng.uniform(0.0, 1000.0, size=2) + offset
    ranges = np.linalg.norm(truth - stations, axis=1) + rng.normal(0.0, 1.0, 4)
    base = cellular.range_fix(np.abs(ranges), stations)
    scaled = cellular.range_fix(np.abs(ranges) * scale, stations * scale)
    np.testing.assert_allclose(scaled / scale, base, rtol=0, atol=1e-9 * (1000.0 + offset))


def test_range_fix_refuses_stations_that_are_one_point_at_the_scale_of_the_ranges():
    from mptrack import cellular
    with pytest.raises(SingularMatrixError, match="^stations: .*negligible against ranges up to 3"):
        cellular.range_fix([1.0, 2.0, 3.0], H.STATIONS * 1e-200)


@settings(max_examples=30, deadline=None)
@given(scale=st.integers(-300, 300).map(lambda e: 10.0 ** e), method=st.sampled_from(riccati.METHODS))
def test_steady_state_does_not_depend_on_the_noise_units(scale, method):
    """(Q, R) in any unit: P scales with them.  The existence checks read a Q of 1e50 or 1e-100 against F
    of 1 as 'not stabilisable', and the iterations stopped after one step once P's squares overflowed."""
    model = LinearGaussianModel(B.F, B.H, B.Q * scale, B.R * scale)
    ss, ref = riccati.steady_state(model, method), riccati.steady_state(B, method)
    np.testing.assert_allclose(ss.P_pred / scale, ref.P_pred, rtol=1e-9)
    np.testing.assert_allclose(ss.K, ref.K, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("h", [1e-100, 1e100])
def test_steady_state_does_not_depend_on_the_measurement_units(h):
    model = LinearGaussianModel(B.F, B.H * h, B.Q, B.R * h * h)
    np.testing.assert_allclose(riccati.steady_state(model).P_pred, riccati.steady_state(B).P_pred, rtol=1e-9)


def test_riccati_residual_of_entries_beyond_1e154():
    """The residual's norms square the entries: formed in units of the largest it is the documented
    ||REKF(Pp) - Pp|| / max(1, ||Pp||) (here the step multiplies P[1, 1] by 1e200; the residual was inf)."""
    model = LinearGaussianModel(np.diag([1.0, 1e100]), [[1.0, 0.0]], np.eye(2), [[1.0]])
    # ||diag(1 - 1e100, 1e300 - 1e100)|| / ||1e100 I|| = 1e300 / (sqrt(2) 1e100); it was inf
    assert riccati.riccati_residual(model, np.eye(2) * 1e100) == pytest.approx(1e200 / np.sqrt(2.0), rel=1e-12)


@settings(max_examples=25, deadline=None)
@given(scale=st.integers(-150, 150).map(lambda e: 10.0 ** e), seed=st.integers(0, 2**32 - 1))
def test_range_ekf_does_not_depend_on_the_units(scale, seed):
    """The range Jacobian divided by max(range, 1e-12 m): below ~1e-10 m the floor was the range."""
    from mptrack import cellular
    rng = np.random.default_rng(seed)
    path = np.array([300.0, 400.0]) + np.cumsum(rng.normal(0.0, 10.0, (5, 2)), axis=0)
    z = np.linalg.norm(path[:, None] - H.STATIONS, axis=-1) + rng.normal(0.0, 5.0, (5, 3))
    args = lambda s: (np.abs(z) * s, H.STATIONS * s, path[0] * s, np.eye(2) * (100.0 * s) ** 2,  # noqa: E731
                      np.eye(2) * (10.0 * s) ** 2, (5.0 * s) ** 2)
    base = cellular.ekf_ranges(*args(1.0))
    scaled = cellular.ekf_ranges(*args(scale))
    np.testing.assert_allclose(scaled.x / scale, base.x, rtol=1e-8, atol=1e-8)


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_gated_filter_outputs_are_finite_or_the_measurements_are_named(data):
    """Every output of the gated filter (estimates, predictions, innovations, NIS, log-likelihood), not
    only x and P: fixes of any magnitude give finite outputs (NaN = not used) or a NonFiniteError on z."""
    z = data.draw(H.real_arrays((4, 2), nonfinite=False).filter(lambda a: a.dtype.kind == "f"))
    gate = data.draw(st.sampled_from([0.999, None]))
    try:
        r = tracking.kalman_filter_gated(H.CV2, [0.0, 1.0, 2.0, 3.0], z, np.zeros(4), np.eye(4) * 100.0,
                                         gate_probability=gate)
    except NonFiniteError as exc:
        assert str(exc).startswith("z: "), exc
        return
    for field in ("x", "P", "x_pred", "P_pred", "innovation", "S", "nis", "loglik"):
        value = np.asarray(getattr(r, field), dtype=float)
        assert not np.isinf(value).any(), field
        assert field not in ("x", "P", "x_pred", "P_pred", "loglik") or np.isfinite(value).all(), field


@pytest.mark.parametrize("call, name", [
    (lambda v: linear.fir_filter(B, np.ones((3, 1)), eps=v, M=3), "eps"),
    (lambda v: batch.fir_filter(B, np.ones((2, 3, 1)), eps=v, M=3), "eps"),
    (lambda v: linear.fir_order(0.5 * np.eye(2), v), "eps"),
    (lambda v: riccati.steady_state(B, "per-step", tol=v), "tol"),
    (lambda v: linear.fit_em(B, np.ones((4, 1)), P0=np.eye(2), tol=v), "tol"),
    (lambda v: linear.fit_ml(lambda q: LinearGaussianModel(B.F, B.H, q * B.Q, B.R), np.ones((4, 1)), {"q": 1.0},
                             P0=np.eye(2), tol=v), "tol"),
], ids=["fir_filter", "batch.fir_filter", "fir_order", "steady_state", "fit_em", "fit_ml"])
@pytest.mark.parametrize("value", [np.inf, np.nan, -1.0, "1e-3"])
def test_tolerances_are_checked_even_where_unused(call, name, value):
    """A tolerance is validated whether or not it is read (fir_filter with M given took eps=inf)."""
    with pytest.raises(MptrackError, match=f"^{name}: "):
        call(value)
