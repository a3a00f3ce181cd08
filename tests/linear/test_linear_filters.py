"""The linear filter family of seed 000 / 002: KF, LF, JKLF, SSKF, SSLF, JSSKLF, FIR, model B
per axis and the 12 implementations of Table 1, cross-checked against each other and against
textbook reference computations written out here."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.stats

from mptrack.errors import NonFiniteError, UnknownNameError
from mptrack.linear import (
    FILTERS,
    IMPLEMENTATIONS,
    fir_coefficients,
    fir_filter,
    fir_order,
    get_filter,
    get_implementation,
    kalman_filter,
    lainiotis_filter,
    per_axis,
    steady_state_filter,
)
from mptrack.models import LinearGaussianModel, assimakis_model_a, assimakis_model_b
from mptrack.result import FilterResult
from mptrack.riccati import steady_state
from mptrack.sim import simulate_linear

RTOL = 1e-10  # the agreement bound for algebraically equivalent filters


def _reference_kf(model, z, x0, P0):
    """Seed 000 eq. 4, written literally (explicit inverse, (I - K H) P form)."""
    F, H, Q, R = model.F, model.H, model.Q, model.R
    x, P = np.asarray(x0, float), np.asarray(P0, float)
    out = {"x": [], "P": [], "x_pred": [], "P_pred": []}
    for zk in z:
        xp = F @ x
        Pp = Q + F @ P @ F.T
        K = Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + R)
        x = (np.eye(len(x)) - K @ H) @ xp + K @ zk
        P = (np.eye(len(x)) - K @ H) @ Pp
        for key, val in (("x", x), ("P", P), ("x_pred", xp), ("P_pred", Pp)):
            out[key].append(val)
    return {key: np.array(val) for key, val in out.items()}


def _prior(model, seed=3):
    rng = np.random.default_rng(seed)
    L = rng.standard_normal((model.n, model.n))
    return rng.standard_normal(model.n), L @ L.T / model.n


# --------------------------------------------------------------------------- KF and LF

@pytest.mark.parametrize("prior", ["papers", "informative"])
def test_kf_and_lf_agree_on_the_papers_models(simulated, prior, assert_rel):
    """Seed 000 Section 6 (i): KF and LF compute the same estimates and covariances."""
    model, _, z = simulated
    x0, P0 = (None, np.zeros((model.n, model.n))) if prior == "papers" else _prior(model)
    kf = kalman_filter(model, z, x0, P0)
    lf = lainiotis_filter(model, z, x0, P0)
    assert_rel(lf.x, kf.x, RTOL, "x")
    assert_rel(lf.P, kf.P, RTOL, "P")


def test_kf_matches_the_textbook_recursion(simulated, assert_rel):
    model, _, z = simulated
    x0, P0 = _prior(model)
    kf = kalman_filter(model, z, x0, P0)
    ref = _reference_kf(model, z, x0, P0)
    for key in ("x", "P", "x_pred", "P_pred"):
        assert_rel(getattr(kf, key), ref[key], 1e-12, key)
    assert kf.method == "KF" and kf.T == len(z) and kf.n == model.n


def test_kf_tracks_the_truth(simulated):
    """Sanity: the estimate is much closer to the truth than the raw measurements allow."""
    model, truth, z = simulated
    kf = kalman_filter(model, z, np.ones(model.n), np.zeros((model.n, model.n)))
    err = kf.x[20:] @ model.H.T - truth[20:] @ model.H.T
    raw = z[20:] - truth[20:] @ model.H.T
    assert np.sqrt(np.mean(err ** 2)) < 0.8 * np.sqrt(np.mean(raw ** 2))


def test_kf_loglik_is_the_joint_gaussian_density_of_the_measurements():
    """log p(z(1..T)) from the KF equals the dense Gaussian density of the stacked z."""
    model = assimakis_model_a(2, dt=0.5, sigma_q2=0.2, sigma_r2=0.3, measurement="position")
    F, H, Q, R = model.F, model.H, model.Q, model.R
    x0, P0 = _prior(model, seed=7)
    T, m = 6, model.m
    z = np.random.default_rng(8).standard_normal((T, m))
    Fp = [np.linalg.matrix_power(F, k) for k in range(T + 1)]
    mean = np.concatenate([H @ Fp[k] @ x0 for k in range(1, T + 1)])
    cov = np.zeros((T * m, T * m))
    for k in range(1, T + 1):
        for j in range(1, T + 1):
            cx = Fp[k] @ P0 @ Fp[j].T + sum(Fp[k - i] @ Q @ Fp[j - i].T for i in range(1, min(k, j) + 1))
            cov[(k - 1) * m:k * m, (j - 1) * m:j * m] = H @ cx @ H.T + (R if k == j else 0.0)
    want = scipy.stats.multivariate_normal(mean, cov).logpdf(z.ravel())
    got = kalman_filter(model, z, x0, P0).loglik
    assert abs(got - want) <= 1e-10 * abs(want)


def test_joseph_form_equals_standard_form(simulated, assert_rel):
    model, _, z = simulated
    x0, P0 = _prior(model)
    std = kalman_filter(model, z, x0, P0)
    jos = kalman_filter(model, z, x0, P0, joseph=True)
    assert_rel(jos.x, std.x, RTOL, "x")
    assert_rel(jos.P, std.P, RTOL, "P")
    assert abs(jos.loglik - std.loglik) <= RTOL * abs(std.loglik)


# --------------------------------------------------------------------------- missing measurements

def _with_gap(z, rows):
    z = np.array(z, dtype=float)
    z[rows] = np.nan
    return z


@pytest.mark.parametrize("run", [kalman_filter, lainiotis_filter], ids=["KF", "LF"])
def test_nan_row_only_predicts(run, simulated):
    model, _, z = simulated
    gap = 40
    res = run(model, _with_gap(z, [gap]), *_prior(model))
    F, Q = model.F, model.Q
    np.testing.assert_allclose(res.x[gap], F @ res.x[gap - 1], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(res.P[gap], F @ res.P[gap - 1] @ F.T + Q, rtol=1e-13, atol=1e-15)
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.P))


def test_kf_restarts_cleanly_after_a_gap(simulated, assert_rel):
    """After a missing row the KF continues exactly as a fresh KF started from the prediction,
    and the log-likelihood skips the missing row."""
    model, _, z = simulated
    gap = 50
    x0, P0 = _prior(model)
    full = kalman_filter(model, _with_gap(z, [gap]), x0, P0)
    head = kalman_filter(model, z[:gap], x0, P0)
    tail = kalman_filter(model, z[gap + 1:], full.x[gap], full.P[gap])
    assert_rel(full.x[gap + 1:], tail.x, 1e-12, "x")
    assert_rel(full.P[gap + 1:], tail.P, 1e-12, "P")
    assert abs(full.loglik - (head.loglik + tail.loglik)) <= 1e-10 * abs(full.loglik)
    np.testing.assert_array_equal(full.x_pred[gap], full.x[gap])


def test_lf_with_gaps_equals_kf_with_gaps(simulated, assert_rel):
    model, _, z = simulated
    zg = _with_gap(z, [0, 10, 11, 12, 90])
    kf = kalman_filter(model, zg, P0=np.zeros((model.n, model.n)))
    lf = lainiotis_filter(model, zg)
    assert_rel(lf.x, kf.x, RTOL, "x")
    assert_rel(lf.P, kf.P, RTOL, "P")


@pytest.mark.parametrize("form", ["kalman", "lainiotis"])
def test_steady_state_filter_nan_row_only_predicts(form):
    model = assimakis_model_a(2)
    _, z = simulate_linear(model, 60, np.random.default_rng(4))
    gap = 30
    x0 = np.ones(4)
    res = steady_state_filter(model, _with_gap(z, [gap]), x0, form=form)
    clean = steady_state_filter(model, z, x0, form=form)
    np.testing.assert_allclose(res.x[gap], model.F @ res.x[gap - 1], rtol=1e-13)
    np.testing.assert_allclose(res.x[:gap], clean.x[:gap], rtol=1e-12, atol=1e-14)
    # covariance "exact": the gap step inflates P by the prediction
    ss = steady_state(model, "dare")
    ex = steady_state_filter(model, _with_gap(z, [gap]), x0, ss.P_filt, covariance="exact", steady=ss)
    np.testing.assert_allclose(ex.P[gap], model.F @ ss.P_filt @ model.F.T + model.Q, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ex.P[gap - 1], ss.P_filt, rtol=1e-10, atol=1e-15)


def test_kf_partial_nan_updates_with_the_observed_components(assert_rel):
    """Model A with the x-axis measurement missing at some steps equals model B run per
    axis (the x filter only predicts there, the y filter updates) and the reduced-H update."""
    model = assimakis_model_a(2)
    _, z = simulate_linear(model, 80, np.random.default_rng(11))
    z = z.copy()
    z[[5, 20, 21, 60], 0] = np.nan
    z[[33], 1] = np.nan
    x0 = np.array([0.5, 0.1, -0.3, 0.2])
    joint = kalman_filter(model, z, x0, np.zeros((model.n, model.n)))
    axes = per_axis(kalman_filter, assimakis_model_b(), z, x0)
    assert_rel(joint.x, axes.x, RTOL, "x")
    assert_rel(joint.P, axes.P, RTOL, "P")
    # the step at row 20 by hand: update with the y row of H only
    k = 20
    F, H, Q, R = model.F, model.H, model.Q, model.R
    xp, Pp = F @ joint.x[k - 1], F @ joint.P[k - 1] @ F.T + Q
    h, r = H[1:], R[1:, 1:]
    K = Pp @ h.T @ np.linalg.inv(h @ Pp @ h.T + r)
    np.testing.assert_allclose(joint.x[k], xp + K @ (z[k, 1:] - h @ xp), rtol=1e-12)
    np.testing.assert_allclose(joint.P[k], (np.eye(4) - K @ h) @ Pp, rtol=1e-10, atol=1e-15)


def test_lf_partial_nan_row_only_predicts():
    """The LF has no partial update (documented): any NaN component makes the step a prediction."""
    model = assimakis_model_a(2)
    _, z = simulate_linear(model, 30, np.random.default_rng(12))
    z = z.copy()
    z[10, 0] = np.nan
    lf = lainiotis_filter(model, z)
    np.testing.assert_allclose(lf.x[10], model.F @ lf.x[9], rtol=1e-13)


# --------------------------------------------------------------------------- steady-state filters

def test_ss_filter_matches_kf_after_convergence(simulated, assert_rel):
    """Seed 000 Section 6 (iii): SSKF and KF outputs coincide once the gain has converged."""
    model, _, z = simulated
    kf = kalman_filter(model, z, P0=np.zeros((model.n, model.n)))
    ss = steady_state(model, "dare")
    for form in ("kalman", "lainiotis"):
        res = steady_state_filter(model, z, form=form)
        assert_rel(res.x[80:], kf.x[80:], 1e-10, f"{form} x")
        assert_rel(res.P[80:], kf.P[80:], 1e-10, f"{form} P")
        np.testing.assert_allclose(res.P[0], ss.P_filt, rtol=1e-10, atol=1e-15)
        # early on they differ: the KF starts from P0 = 0, the SS filter from the limit gain
        assert np.max(np.abs(res.x[0] - kf.x[0])) > 1e-3 * np.max(np.abs(kf.x[0]))


def test_kf_started_in_steady_state_is_the_ss_filter_at_every_step(simulated, assert_rel):
    model, _, z = simulated
    ss = steady_state(model, "dare")
    x0 = np.linspace(-1.0, 1.0, model.n)
    kf = kalman_filter(model, z, x0, ss.P_filt)
    for form in ("kalman", "lainiotis"):
        res = steady_state_filter(model, z, x0, form=form)
        assert_rel(res.x, kf.x, RTOL, form)


def test_sslf_equals_sskf(simulated, assert_rel):
    """Eq. 15: A_KF = A_LF, B_KF = B_LF, so the two steady-state filters coincide."""
    model, _, z = simulated
    x0 = np.ones(model.n)
    sskf = steady_state_filter(model, z, x0, form="kalman")
    sslf = steady_state_filter(model, z, x0, form="lainiotis")
    assert (sskf.method, sslf.method) == ("SSKF", "SSLF")
    assert_rel(sslf.x, sskf.x, RTOL, "x")
    assert_rel(sslf.P, sskf.P, RTOL, "P")


def test_ss_filter_is_eq_9_written_out():
    model = assimakis_model_b(measurement="position")
    z = np.random.default_rng(13).standard_normal((25, 1))
    ss = steady_state(model, "doubling")
    x = np.array([1.0, -1.0])
    want = []
    for zk in z:
        x = ss.A @ x + ss.B @ zk
        want.append(x)
    got = steady_state_filter(model, z, [1.0, -1.0], steady=ss)
    np.testing.assert_allclose(got.x, want, rtol=1e-13, atol=1e-15)


def test_exact_covariance_of_the_constant_gain_filter(simulated):
    """covariance='exact' is the true error covariance of the SS filter: never below the KF's
    optimal covariance (same prior), equal to Pe when started there, converging to Pe."""
    model, _, z = simulated
    ss = steady_state(model, "dare")
    P0 = np.eye(model.n)
    ex = steady_state_filter(model, z, None, P0, covariance="exact", steady=ss)
    kf = kalman_filter(model, z, None, P0)
    for k in range(0, len(z), 7):
        gap = np.linalg.eigvalsh(ex.P[k] - kf.P[k])[0]
        assert gap >= -1e-12 * np.linalg.norm(kf.P[k]), k
    np.testing.assert_allclose(ex.P[-1], ss.P_filt, rtol=1e-9, atol=1e-14)
    at_pe = steady_state_filter(model, z[:30], None, ss.P_filt, covariance="exact", steady=ss)
    np.testing.assert_allclose(at_pe.P, np.broadcast_to(ss.P_filt, at_pe.P.shape), rtol=1e-10, atol=1e-15)


# --------------------------------------------------------------------------- FIR filter (eqs. 20-22)

@pytest.mark.parametrize("measurement, want", [("printed", 17), ("position", 20)])
@pytest.mark.parametrize("factory", [assimakis_model_b, lambda m: assimakis_model_a(2, measurement=m),
                                     lambda m: assimakis_model_a(3, measurement=m)],
                         ids=["B", "A2", "A3"])
def test_fir_order_of_the_papers_example(factory, measurement, want):
    """Seed 000 Section 7: eps = 1e-3, spectral norm -> M = 17 (as printed); 20 with H = [1 0]."""
    model = factory(measurement=measurement) if factory is assimakis_model_b else factory(measurement)
    A = steady_state(model, "dare").A
    assert fir_order(A) == want
    assert fir_order(A, eps=1e-3, norm=2) == want


@pytest.mark.parametrize("norm", [2, "fro", 1, np.inf])
@pytest.mark.parametrize("eps", [1e-1, 1e-3, 1e-6])
def test_fir_order_is_the_first_power_below_eps(norm, eps):
    A = steady_state(assimakis_model_a(2), "dare").A
    M = fir_order(A, eps=eps, norm=norm)
    assert np.linalg.norm(np.linalg.matrix_power(A, M), norm) < eps
    assert np.linalg.norm(np.linalg.matrix_power(A, M - 1), norm) >= eps


def test_fir_order_is_at_least_one():
    """Eq. 22 needs M >= 1 (M = 0 is an empty sum); with eps above ||A^0|| = 1 the order is 1."""
    A = 0.5 * np.eye(2)
    assert fir_order(A, eps=2.0) == 1
    model = assimakis_model_b()
    z = np.ones((4, 1))
    res = fir_filter(model, z, eps=2.0)
    np.testing.assert_allclose(res.x, z @ steady_state(model).B.T)


def test_fir_coefficients_are_powers_of_a_times_b():
    ss = steady_state(assimakis_model_a(2), "dare")
    C = fir_coefficients(ss.A, ss.B, 6)
    assert C.shape == (6, 4, 2)
    for j in range(6):
        np.testing.assert_allclose(C[j], np.linalg.matrix_power(ss.A, j) @ ss.B, rtol=1e-13, atol=1e-16)


def test_fir_with_explicit_order_is_eq_22_written_out():
    model = assimakis_model_b()
    ss = steady_state(model, "dare")
    z = np.random.default_rng(14).standard_normal((12, 1))
    res = fir_filter(model, z, M=5)
    for k in range(4, 12):
        want = sum(np.linalg.matrix_power(ss.A, j) @ ss.B @ z[k - j] for j in range(5))
        np.testing.assert_allclose(res.x[k], want, rtol=1e-12)
    assert res.method == "FIR"
    np.testing.assert_array_equal(res.P[3], ss.P_filt)


@pytest.mark.parametrize("norm", [2, "fro"])
def test_fir_matches_ss_filter_to_the_eps_bound(simulated, norm, assert_rel):
    """x_ss(k) - x_fir(k) = A^M x_ss(k-M) (eq. 21 vs 22), so
    ||x_fir(k) - x_ss(k)|| <= ||A^M|| ||x_ss(k-M)|| < eps ||x_ss(k-M)|| for k >= M."""
    model, _, z = simulated
    ss = steady_state(model, "dare")
    x0 = np.ones(model.n)
    sf = steady_state_filter(model, z, x0, steady=ss).x
    fir = fir_filter(model, z, x0, norm=norm, steady=ss).x
    M = fir_order(ss.A, 1e-3, norm)
    AM = np.linalg.matrix_power(ss.A, M)
    bound = np.linalg.norm(AM, 2)
    assert bound < 1e-3 or norm != 2
    prev = np.vstack([x0, sf])  # prev[k] = x_ss(k), k = 0..T
    for row in range(M - 1, len(z)):
        k = row + 1  # time index of this row
        diff = sf[row] - fir[row]
        np.testing.assert_allclose(diff, AM @ prev[k - M], rtol=1e-6, atol=1e-12 * np.linalg.norm(sf[row]))
        assert np.linalg.norm(diff) <= bound * np.linalg.norm(prev[k - M]) * (1 + 1e-9) + 1e-14
    # the bound is not vacuous: the FIR and the SS filter do differ
    assert np.max(np.abs(sf[M:] - fir[M:])) > 0


def test_fir_truncated_warmup_equals_ss_filter_from_zero(simulated, assert_rel):
    """With x0 = 0 the truncated sum over the available measurements is the SS filter (k < M)."""
    model, _, z = simulated
    ss = steady_state(model, "dare")
    M = fir_order(ss.A)
    sf = steady_state_filter(model, z, steady=ss).x
    fir = fir_filter(model, z, steady=ss, warmup="truncate").x
    assert_rel(fir[:M - 1], sf[:M - 1], 1e-12, "x")


def test_fir_steady_state_warmup_runs_the_ss_filter_first(simulated):
    model, _, z = simulated
    x0 = 2.0 * np.ones(model.n)
    ss = steady_state(model, "dare")
    M = fir_order(ss.A)
    sf = steady_state_filter(model, z, x0, steady=ss).x
    fir = fir_filter(model, z, x0, steady=ss, warmup="steady-state").x
    np.testing.assert_allclose(fir[:M - 1], sf[:M - 1], rtol=1e-13)
    trunc = fir_filter(model, z, x0, steady=ss, warmup="truncate").x
    np.testing.assert_array_equal(fir[M - 1:], trunc[M - 1:])


def test_fir_rejects_missing_measurements():
    model = assimakis_model_b()
    z = np.ones((30, 1))
    z[7] = np.nan
    with pytest.raises(NonFiniteError, match="z"):
        fir_filter(model, z)


# --------------------------------------------------------------------------- joins, registry, per axis

def test_filter_registry_names():
    assert set(FILTERS) == {"KF", "LF", "JKLF", "SSKF", "SSLF", "JSSKLF", "FIR"}
    assert get_filter("jssklf") is FILTERS["JSSKLF"]
    for name in ("KF", "LF", "JKLF"):
        assert FILTERS[name].system == "time invariant"
    for name in ("SSKF", "SSLF", "JSSKLF", "FIR"):
        assert FILTERS[name].system == "steady state"
    with pytest.raises(UnknownNameError, match="filter"):
        get_filter("EKF")


@pytest.mark.parametrize("model", [assimakis_model_a(2), assimakis_model_b(measurement="position")],
                         ids=["A2", "B-position"])
def test_jklf_is_the_average_of_kf_and_lf(model):
    """Eq. 8 (and eq. 16 for the steady-state join): weight 50 % each."""
    _, z = simulate_linear(model, 80, np.random.default_rng(17))
    x0, P0 = _prior(model)
    kf, lf = FILTERS["KF"].run(model, z, x0, P0), FILTERS["LF"].run(model, z, x0, P0)
    j = FILTERS["JKLF"].run(model, z, x0, P0)
    np.testing.assert_allclose(j.x, 0.5 * (kf.x + lf.x), rtol=1e-15, atol=1e-300)
    np.testing.assert_allclose(j.P, 0.5 * (kf.P + lf.P), rtol=1e-15, atol=1e-300)
    sk, sl = FILTERS["SSKF"].run(model, z, x0, P0), FILTERS["SSLF"].run(model, z, x0, P0)
    js = FILTERS["JSSKLF"].run(model, z, x0, P0)
    np.testing.assert_allclose(js.x, 0.5 * (sk.x + sl.x), rtol=1e-15, atol=1e-300)
    assert (j.method, js.method) == ("JKLF", "JSSKLF")


def _axes_prior(axis_model, axes, seed=21):
    rng = np.random.default_rng(seed)
    blocks = []
    for _ in range(axes):
        L = rng.standard_normal((axis_model.n, axis_model.n))
        blocks.append(L @ L.T)
    return rng.standard_normal(axes * axis_model.n), scipy.linalg.block_diag(*blocks)


@pytest.mark.parametrize("name", list(FILTERS))
@pytest.mark.parametrize("axes", [2, 3])
@pytest.mark.parametrize("measurement", ["printed", "position"])
def test_model_a_equals_model_b_per_axis(name, axes, measurement, assert_rel):
    """Seed 000 Section 6 (iv): model A and model B (one filter per axis, joined by eqs. 17-18)
    produce the same outputs, for every filter."""
    axis_model = assimakis_model_b(measurement=measurement)
    joint = assimakis_model_a(axes, measurement=measurement)
    _, z = simulate_linear(joint, 60, np.random.default_rng(axes))
    x0, P0 = _axes_prior(axis_model, axes)
    spec = FILTERS[name]
    a = spec.run(joint, z, x0, P0)
    b = per_axis(spec.run, axis_model, z, x0, P0)
    assert_rel(b.x, a.x, RTOL, "x")
    assert_rel(b.P, a.P, RTOL, "P")
    assert b.x.shape == (60, 2 * axes) and b.P.shape == (60, 2 * axes, 2 * axes)


def test_per_axis_keeps_predictions_and_sums_logliks():
    axis_model = assimakis_model_b()
    joint = assimakis_model_a(3)
    _, z = simulate_linear(joint, 40, np.random.default_rng(5))
    x0, P0 = _axes_prior(axis_model, 3)
    b = per_axis(kalman_filter, axis_model, z, x0, P0)
    a = kalman_filter(joint, z, x0, P0)
    np.testing.assert_allclose(b.x_pred, a.x_pred, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(b.P_pred, a.P_pred, rtol=1e-10, atol=1e-14)
    assert abs(b.loglik - a.loglik) <= 1e-10 * abs(a.loglik)
    # the joined covariance is exactly block-diagonal
    assert np.all(b.P[:, 0:2, 2:] == 0.0) and np.all(b.P[:, 2:4, 4:] == 0.0)
    lf = per_axis(lainiotis_filter, axis_model, z, x0, P0)
    assert lf.x_pred is None and lf.loglik is None


def test_per_axis_accepts_p0_block_diagonal_to_rounding():
    """A steady-state Pe of model A has off-block entries of ~1e-18 (rounding); it is the natural
    prior for the model B filters and should be accepted."""
    joint = assimakis_model_a(2)
    noise = 1e-18 * np.array([[0, 0, 1, -2], [0, 0, 3, 1], [1, 3, 0, 0], [-2, 1, 0, 0]])
    P0 = scipy.linalg.block_diag(*[steady_state(assimakis_model_b(), "dare").P_filt] * 2) + noise
    _, z = simulate_linear(joint, 10, np.random.default_rng(1))
    res = per_axis(kalman_filter, assimakis_model_b(), z, None, P0)
    np.testing.assert_allclose(res.x, kalman_filter(joint, z, None, P0).x, rtol=1e-10, atol=1e-14)


# --------------------------------------------------------------------------- Table 1

def test_table_1_numbering():
    table = [(imp.number, imp.model, imp.filter) for imp in IMPLEMENTATIONS]
    filters = ["KF", "LF", "JKLF", "SSKF", "SSLF", "JSSKLF"]
    assert table == [(i + 1, "A" if i < 6 else "B", filters[i % 6]) for i in range(12)]
    assert [imp.system for imp in IMPLEMENTATIONS[:6]] == ["time invariant"] * 3 + ["steady state"] * 3
    assert get_implementation(9).name == "JKLF-B"
    assert get_implementation("sslf-a").number == 5
    with pytest.raises(UnknownNameError, match="implementation"):
        get_implementation(13)
    with pytest.raises(UnknownNameError, match="implementation"):
        get_implementation("KF-C")


@pytest.mark.parametrize("axes", [2, 3])
def test_all_twelve_implementations_give_the_same_estimates(axes, assert_rel):
    """Started from the steady-state covariance, all 12 implementations of Table 1 produce
    the same estimates at every step; from the papers' P0 = 0 the time-invariant ones agree
    with each other at every step, the steady-state ones too, and both groups after convergence."""
    joint = assimakis_model_a(axes)
    _, z = simulate_linear(joint, 120, np.random.default_rng(40 + axes))
    Pe = scipy.linalg.block_diag(*[steady_state(assimakis_model_b(), "dare").P_filt] * axes)
    x0 = np.linspace(-1, 1, 2 * axes)
    runners = {imp.name: imp.prepare(axes=axes) for imp in IMPLEMENTATIONS}
    ref = runners["KF-A"](z, x0, Pe)
    for name, run in runners.items():
        res = run(z, x0, Pe)
        assert isinstance(res, FilterResult)
        assert_rel(res.x, ref.x, RTOL, name)
    ti = {n: r(z) for n, r in runners.items() if n.split("-")[0] in ("KF", "LF", "JKLF")}
    st = {n: r(z) for n, r in runners.items() if n not in ti}
    for name, res in ti.items():
        assert_rel(res.x, ti["KF-A"].x, RTOL, name)
        assert_rel(res.P, ti["KF-A"].P, RTOL, name)
    for name, res in st.items():
        assert_rel(res.x, st["SSKF-A"].x, RTOL, name)
        assert_rel(res.x[80:], ti["KF-A"].x[80:], 1e-9, name)


# --------------------------------------------------------------------------- statistical consistency

def test_kf_is_consistent_nees_nis():
    """Fixed seed: with the true prior the normalised estimation error squared averages n and the
    normalised innovation squared averages m (99.9 % chi-square interval over 200 runs)."""
    model = assimakis_model_a(2, measurement="position")
    runs, T = 200, 40
    rng = np.random.default_rng(2024)
    x_start = np.array([1.0, 0.5, -2.0, 0.1])
    nees, nis = [], []
    for _ in range(runs):
        truth, z = simulate_linear(model, T, rng, x0=x_start)
        kf = kalman_filter(model, z, x_start, np.zeros((4, 4)))
        e = truth[-1] - kf.x[-1]
        nees.append(e @ np.linalg.solve(kf.P[-1], e))
        innov = z[-1] - model.H @ kf.x_pred[-1]
        S = model.H @ kf.P_pred[-1] @ model.H.T + model.R
        nis.append(innov @ np.linalg.solve(S, innov))
    for values, dof in ((nees, model.n), (nis, model.m)):
        lo, hi = scipy.stats.chi2.ppf([0.0005, 0.9995], dof * runs) / runs
        assert lo <= np.mean(values) <= hi, (np.mean(values), lo, hi)


def test_wrong_noise_level_fails_the_consistency_check():
    """The NEES check above can fail: a filter assuming 100x too little process noise."""
    model = assimakis_model_a(2, measurement="position")
    wrong = assimakis_model_a(2, sigma_q2=1e-4, measurement="position")
    rng = np.random.default_rng(2024)
    nees = []
    for _ in range(50):
        truth, z = simulate_linear(model, 40, rng)
        kf = kalman_filter(wrong, z, P0=np.zeros((4, 4)))
        e = truth[-1] - kf.x[-1]
        nees.append(e @ np.linalg.solve(kf.P[-1], e))
    assert np.mean(nees) > scipy.stats.chi2.ppf(0.9995, 4 * 50) / 50


def test_filters_accept_general_models():
    """Nothing in the filters is specific to the papers' models (n = 3, m = 2, dense matrices)."""
    F = np.array([[0.9, 0.2, 0.0], [-0.1, 0.8, 0.3], [0.0, 0.1, 0.7]])
    H = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, -1.0]])
    G = np.array([[1.0], [0.5], [0.2]])
    model = LinearGaussianModel.from_noise_gain(F, H, G, [[0.3]], [[0.2, 0.05], [0.05, 0.4]])
    _, z = simulate_linear(model, 50, np.random.default_rng(9))
    x0, P0 = _prior(model)
    kf = kalman_filter(model, z, x0, P0)
    ref = _reference_kf(model, z, x0, P0)
    np.testing.assert_allclose(kf.x, ref["x"], rtol=1e-12, atol=1e-14)
    lf = lainiotis_filter(model, z, x0, P0)
    np.testing.assert_allclose(lf.x, kf.x, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("name", ["KF", "LF", "SSKF", "SSLF", "FIR"])
def test_input_layouts_and_dtypes_do_not_change_results(name):
    """Strided, Fortran-ordered, read-only, integer and float32 inputs give the same numbers as
    contiguous float64 ones (the compiled loops must not depend on memory layout)."""
    model = assimakis_model_a(3)
    big = np.random.default_rng(30).standard_normal((40, 6))
    ref = FILTERS[name].run(model, np.ascontiguousarray(big[::2, ::2]), np.arange(6.0), 2.0 * np.eye(6))
    read_only = np.ascontiguousarray(big[::2, ::2])
    read_only.setflags(write=False)
    # a read-only z is its own numba specialisation (a compile of several seconds on a cold
    # cache): checked for the KF only
    for z in (big[::2, ::2], np.asfortranarray(big[::2, ::2])) + ((read_only,) if name == "KF" else ()):
        res = FILTERS[name].run(model, z, np.arange(6), 2 * np.eye(6, dtype=int))
        np.testing.assert_array_equal(res.x, ref.x)
        np.testing.assert_array_equal(res.P, ref.P)
    z32 = big[::2, ::2].astype(np.float32)
    res = FILTERS[name].run(model, z32, np.arange(6.0), 2.0 * np.eye(6))
    assert res.x.dtype == np.float64
    np.testing.assert_allclose(res.x, FILTERS[name].run(model, z32.astype(np.float64), np.arange(6.0),
                                                        2.0 * np.eye(6)).x, rtol=0, atol=0)
