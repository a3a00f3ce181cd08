"""The columnar tracking engine against the per-track reference, and its building blocks.

The engine (:mod:`mptrack.tracking._engine`) runs the gated filter of every
track in one compiled pass with closed-form per-axis transitions; the
reference (:func:`mptrack.tracking.track_gated`, :func:`rts_smoother_gated`) runs the
library's general 4 x 4 / 6 x 6 filter with Van Loan discretisation, track by
track.  They must agree to rounding on tracks with gaps, outliers, manoeuvres,
jumps (resets), single fixes and repeated time stamps.
"""

from math import factorial

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.models import constant_acceleration_continuous, constant_velocity_continuous, discretize_intervals
from mptrack.tracking import FLAGS, get_model, nis_threshold, rts_smoother_gated, track_gated
from mptrack.tracking._fixes import fix_error_model
from mptrack.tracking._chain import chain_transition
from mptrack.tracking._engine import filter_tracks
from mptrack.tracking._likelihood import loglik_tracks

GATE = nis_threshold(0.999, 2)


def random_tracks(rng, n_tracks, max_len=70, speed=10.0, gap_s=(60.0, 300.0)):
    """Flat columns of tracks with irregular intervals (some repeated times, some gaps of ``gap_s``),
    noisy fixes, 5 % outliers, and a 1 km jump in some tracks; per-fix unit variances w and per-track
    c, q."""
    lens = rng.integers(1, max_len, n_tracks)
    offsets = np.r_[0, np.cumsum(lens)].astype(np.int64)
    N = int(offsets[-1])
    t, ze, zn = np.empty(N), np.empty(N), np.empty(N)
    for b in range(n_tracks):
        L = lens[b]
        dt = rng.uniform(0.2, 20.0, L)
        dt[rng.random(L) < 0.05] = 0.0                 # repeated time stamps
        dt[rng.random(L) < 0.03] = rng.uniform(*gap_s)    # gaps
        tt = 1e9 + np.cumsum(dt)
        v = rng.normal(0, speed, 2)
        e = v[0] * (tt - tt[0]) + rng.normal(0, 4, L)
        n = v[1] * (tt - tt[0]) + rng.normal(0, 4, L)
        out = rng.random(L) < 0.05
        e[out] += rng.choice([-1, 1], out.sum()) * rng.uniform(80, 400, out.sum())
        if L > 30 and rng.random() < 0.5:
            e[L // 2:] += 1000.0                            # the terminal jumps: a restart
        s = slice(offsets[b], offsets[b + 1])
        t[s], ze[s], zn[s] = tt, e, n
    w = rng.uniform(0.5, 40.0, N)
    c = rng.uniform(0.3, 3.0, n_tracks)
    q = rng.uniform(0.01, 5.0, n_tracks)   # m^2/s^3 for cv; the ca tests divide by 100 (m^2/s^5)
    return offsets, t, ze, zn, w, c, q


def run_engine(order, offsets, t, ze, zn, w, c, q, smooth, gate=GATE, sb2=None, tau=None, max_gap=np.inf):
    """The engine on the tracks; the fix error's slow part sb2 (default none), tau (default 1 h) per track."""
    N, B = len(t), len(offsets) - 1
    n = order + 1
    X, P = np.empty((N, 2, n)), np.empty((N, n, n))
    nis, flag, stats = np.empty(N), np.empty(N, np.int8), np.zeros((B, 6))
    prior = get_model({2: "cv", 3: "ca"}[order]).prior_variances
    sb2 = np.zeros(B) if sb2 is None else sb2
    tau = np.full(B, 3600.0) if tau is None else tau
    filter_tracks(offsets, t, ze, zn, w, c, q, sb2, tau, order, prior, gate, order + 1, max_gap, True, smooth, X, P,
                  nis, flag, stats)
    return X, P, nis, flag, stats


def assert_within(actual, desired, atol):
    """|actual - desired| <= atol elementwise (atol an array), reporting the worst element."""
    excess = np.abs(actual - desired) / atol
    i = np.unravel_index(int(np.argmax(excess)), excess.shape)
    assert excess[i] <= 1, f"at {i}: {actual[i]!r} vs {desired[i]!r}, {excess[i]:.3g} x the tolerance"


def back_amplification(t, flag, order):
    """Per row, the factor by which a restart's back prediction (the rejected run's fixes before the
    restart take its state predicted back over d seconds) can scale a rounding difference of the
    restart state: sum_p d^p / p! (the row norm of F(-d)); 1 elsewhere."""
    reset, outlier = FLAGS.index("reset"), FLAGS.index("outlier")
    amp = np.ones(len(t))
    for j in np.flatnonzero(flag == reset):
        last = j
        for k in range(j + 1, len(t)):
            if flag[k] not in (reset, outlier):
                break
            if flag[k] == reset:
                last = k
        d = t[last] - t[j]
        amp[j] = sum(d ** p / factorial(p) for p in range(order))
    return amp


def run_reference(spec, b, offsets, t, ze, zn, w, c, q, smooth, sb2=None, tau=None, max_gap=None):
    """The per-track reference on track b: (its rows, the gated run, its filtered or smoothed result,
    the index of the slow fix error in its per-axis state or None)."""
    s = slice(offsets[b], offsets[b + 1])
    slow = 0.0 if sb2 is None else float(sb2[b])
    model, levels, info, prior = fix_error_model(spec, q[b], slow, 3600.0 if tau is None else float(tau[b]))
    g = track_gated(model, t[s], np.column_stack([ze[s], zn[s]]), (c[b] * w[s])[:, None, None] * np.eye(2), prior,
                    gate_probability=0.999, manoeuvre_noise=levels, prior_information=info, max_gap_s=max_gap)
    return s, g, rts_smoother_gated(g) if smooth else g


def slow_error(rng, B, slow):
    """Per-track slow fix error (stationary variance, time constant) of the tests: none, or random."""
    if not slow:
        return None, None
    return rng.uniform(0.5, 40.0, B), rng.choice([30.0, 600.0, np.inf], B)


def assert_engine_equals_reference(order, X, P, nis, flag, stats, s, g, ref, t, r, tol=1e-10, smooth=False):
    """Flags exactly; states, covariances, NIS and log-likelihood to ``tol`` on the scale of the computation."""
    np.testing.assert_array_equal(g.flag, flag[s])
    nr = ref.x.shape[1] // 2               # the reference's states per axis: order, + 1 with a slow error
    # to tol on the scale of the computation: the largest predicted variance of the track (a 2000 s gap
    # predicts ~1e10 m^2, and the update cancels it down to the fix's variance)
    p_scale = float(np.abs(g.P_pred if g.P_pred is not None else g.P).max())
    x_scale = float(np.abs(ref.x).max()) + np.sqrt(p_scale)
    # a restart's back prediction scales the restart state's rounding by its amplification
    amp = back_amplification(t[s], flag[s], order)
    for axis in range(2):
        for d in range(nr):
            assert_within(X[s][:, axis, d], ref.x[:, axis * nr + d], tol * x_scale * amp)
    assert_within(P[s][:, :nr, :nr], ref.P[:, :nr, :nr], tol * p_scale * amp[:, None, None] ** 2)
    assert_within(P[s][:, :nr, :nr], ref.P[:, nr:, nr:], tol * p_scale * amp[:, None, None] ** 2)
    if nr == order:                          # no slow error: the engine's state for it stays 0
        assert not X[s][:, :, order].any() and not P[s][:, order].any()
    if not smooth:
        # NIS = nu^2 / S: S carries the covariances' error (tol of p_scale), over S >= the smallest r
        np.testing.assert_allclose(nis[s], g.nis, rtol=max(tol, tol * p_scale / r.min()), equal_nan=True)
    assert stats[0] == pytest.approx(g.loglik, rel=tol, abs=1e-8)


@pytest.mark.parametrize("name", ["cv", "ca"])
@pytest.mark.parametrize("smooth", [False, True])
@pytest.mark.parametrize("slow", [False, True])
def test_engine_equals_the_per_track_reference(name, smooth, slow):
    rng = np.random.default_rng({"cv": 1, "ca": 2}[name] + 10 * smooth + 100 * slow)
    offsets, t, ze, zn, w, c, q = random_tracks(rng, 60)
    q = q if name == "cv" else q / 100.0
    B = len(offsets) - 1
    sb2, tau = slow_error(rng, B, slow)
    max_gap = 200.0 if slow else None      # gaps of 60-300 s: some start a new segment
    spec = get_model(name)
    order = spec.order
    X, P, nis, flag, stats = run_engine(order, offsets, t, ze, zn, w, c, q, smooth, sb2=sb2, tau=tau,
                                        max_gap=np.inf if max_gap is None else max_gap)
    seen = set()
    for b in range(B):
        s, g, ref = run_reference(spec, b, offsets, t, ze, zn, w, c, q, smooth, sb2=sb2, tau=tau, max_gap=max_gap)
        assert_engine_equals_reference(order, X, P, nis, flag, stats[b], s, g, ref, t, c[b] * w[s], smooth=smooth)
        seen.update(FLAGS[f] for f in flag[s])
        if slow:
            assert (flag[s][1:][np.diff(t[s]) > max_gap] == FLAGS.index("init")).all()
    # the test data exercise every rule
    assert {"init", "update", "outlier", "reset", "manoeuvre"} <= seen


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), order=st.sampled_from([2, 3]), slow=st.booleans())
def test_engine_equals_reference_on_random_tracks(seed, order, slow):
    rng = np.random.default_rng(seed)
    offsets, t, ze, zn, w, c, q = random_tracks(rng, 4, max_len=40)
    q = q if order == 2 else q / 100.0
    sb2, tau = slow_error(rng, 4, slow)
    X, P, nis, flag, _ = run_engine(order, offsets, t, ze, zn, w, c, q, smooth=True, sb2=sb2, tau=tau)
    spec = get_model({2: "cv", 3: "ca"}[order])
    for b in range(4):
        s, g, ref = run_reference(spec, b, offsets, t, ze, zn, w, c, q, smooth=True, sb2=sb2, tau=tau)
        np.testing.assert_array_equal(g.flag, flag[s])
        nr = ref.x.shape[1] // 2
        # the scale of the main test: the track's largest predicted variance (seed 154944337: a 254 s gap
        # of a ca track predicts 2.7e10 m^2; engine and reference are then 2.6e-6 and 1.2e-6 m from an
        # 80-bit computation of the same smoother, beyond 1e-10 of the smoothed covariances' scale)
        p_scale = np.abs(g.P_pred if g.P_pred is not None else g.P).max()
        x_scale = float(np.abs(ref.x).max()) + np.sqrt(float(p_scale))
        amp = back_amplification(t[s], flag[s], order)
        assert_within(X[s][:, 0, 0], ref.x[:, 0], 1e-10 * x_scale * amp)
        assert_within(X[s][:, 1, 1], ref.x[:, nr + 1], 1e-10 * x_scale * amp)


def test_single_fix_tracks_and_first_fixes():
    """A track of one fix is its fix (flag init, no NIS); every track starts at its first fix with
    the fix's own variance and no velocity."""
    offsets = np.array([0, 1, 3], dtype=np.int64)
    t = np.array([5.0, 1.0, 2.0])
    ze, zn = np.array([10.0, -3.0, 7.0]), np.array([20.0, 4.0, 4.0])
    w = np.array([4.0, 9.0, 9.0])
    X, P, nis, flag, stats = run_engine(2, offsets, t, ze, zn, w, np.ones(2), np.ones(2), smooth=True)
    assert FLAGS[flag[0]] == "init" and FLAGS[flag[1]] == "init" and np.isnan(nis[[0, 1]]).all()
    np.testing.assert_array_equal(X[0, :, 0], [10.0, 20.0])
    assert P[0, 0, 0] == 4.0 and P[0, 1, 1] == 900.0 and stats[0, 1] == 0 and not P[0, 2].any()
    assert np.isfinite(X).all() and np.isfinite(P).all()


@settings(max_examples=40, deadline=None)
@given(dt=st.floats(-100.0, 100.0), q=st.floats(1e-3, 10.0))
def test_closed_form_transitions_equal_van_loan(dt, q):
    """The engine's F and Q (q = 1, scaled) equal the exact Van Loan discretisation of the models."""
    for order, model in ((2, constant_velocity_continuous(q, axes=1)),
                         (3, constant_acceleration_continuous(q, axes=1))):
        F, Qu = np.empty((order, order)), np.empty((order, order))
        chain_transition(order, dt, F, Qu)
        F_ref, Q_ref = discretize_intervals(model, np.array([abs(dt)]))
        if dt >= 0:
            np.testing.assert_allclose(F, F_ref[0], rtol=1e-13, atol=1e-13)
            np.testing.assert_allclose(q * Qu, Q_ref[0], rtol=1e-9, atol=1e-12 * max(1.0, np.abs(Q_ref).max()))
        else:  # F(-dt) is the inverse of F(dt)
            np.testing.assert_allclose(F @ F_ref[0], np.eye(order), atol=1e-9 * max(1.0, abs(dt)) ** order)


def dense_conditional_loglik(t, z, w, c, q, order):
    """log p(z[order:] | z[:order]) of both axes with a flat prior on the initial state, by dense Gaussian
    algebra: z = X b + e with e's covariance from the chain's state covariances, and the diffuse
    likelihood of de Jong (1991) plus log |det X[:order]| (the flat-prior density of the first fixes)."""
    N = len(t)
    F, Qu = np.empty((order, order)), np.empty((order, order))
    V = [np.zeros((order, order))]
    for k in range(1, N):
        chain_transition(order, t[k] - t[k - 1], F, Qu)
        V.append(F @ V[-1] @ F.T + q * Qu)
    S0 = np.empty((N, N))
    for j in range(N):
        for k in range(j, N):
            chain_transition(order, t[k] - t[j], F, Qu)
            S0[j, k] = S0[k, j] = (F @ V[j])[0, 0]
    S0 += np.diag(c * w)
    X = np.array([[(tk - t[0]) ** j / factorial(j) for j in range(order)] for tk in t])
    Si = np.linalg.inv(S0)
    A = X.T @ Si @ X
    total = 0.0
    for y in z.T:
        b = np.linalg.solve(A, X.T @ Si @ y)
        quad = y @ Si @ y - b @ A @ b
        total += -0.5 * ((N - order) * np.log(2 * np.pi) + np.linalg.slogdet(S0)[1] + np.linalg.slogdet(A)[1] + quad)
        total += np.log(abs(np.linalg.det(X[:order])))
    return total


@pytest.mark.parametrize("order", [2, 3])
def test_diffuse_likelihood_equals_dense_gaussian_algebra(order):
    rng = np.random.default_rng(order)
    N = 24
    t = np.cumsum(rng.uniform(0.3, 3.0, N))
    z = rng.normal(0, 3, (N, 2)) + np.outer(t, [2.0, -1.0])
    w = rng.uniform(0.5, 3.0, N)
    c, q = 2.0, 0.3
    out = np.zeros((1, 3))
    loglik_tracks(np.array([0, N]), np.array([True]), t, z[:, 0].copy(), z[:, 1].copy(), w, np.zeros(N, np.int8),
                  np.array([c]), np.array([q]), order, out)
    E, L, n = out[0]
    assert n == 2 * (N - order)
    assert -0.5 * (E + L + n * np.log(2 * np.pi)) == pytest.approx(dense_conditional_loglik(t, z, w, c, q, order),
                                                                   rel=1e-9)


def test_a_jump_restarts_and_scattered_outliers_do_not():
    rng = np.random.default_rng(4)
    t = np.arange(60.0)
    e = 3.0 * t + rng.normal(0, 1, 60)
    n = -1.0 * t + rng.normal(0, 1, 60)
    e_jump = e.copy()
    e_jump[30:] += 500.0
    e_wild = e.copy()
    e_wild[20:26] += rng.uniform(-400, 400, 6) + 200 * np.sign(rng.uniform(-1, 1, 6))
    offsets = np.array([0, 60, 120], dtype=np.int64)
    X, P, nis, flag, stats = run_engine(2, offsets, np.r_[t, t], np.r_[e_jump, e_wild], np.r_[n, n],
                                        np.ones(120), np.ones(2), np.full(2, 0.05), smooth=False)
    names = np.array(FLAGS)[flag]
    # the run of three rejected fixes restarts the track at its last, and its first two take the
    # restart state predicted back: they are the new stretch's start, not outliers
    assert names[30:33].tolist() == ["reset", "reset", "reset"]
    assert (names[33:60] == "update").all() and stats[0, 3] == 1
    for k in (30, 31, 32):
        np.testing.assert_allclose(X[k, 0, :2], [e_jump[k], 3.0], atol=3.0)
    assert (names[80:86] == "outlier").all() and stats[1, 3] == 0 and (names[86:] == "update").all()


def test_extreme_gaps_agree_to_their_conditioning():
    """Gaps of 200-2000 s at up to q = 5 m^2/s^3 predict variances ~1e10 m^2; both implementations lose
    digits inverting them in the smoother, and agree to 1e-6 of the state's scale."""
    rng = np.random.default_rng(7)
    offsets, t, ze, zn, w, c, q = random_tracks(rng, 20, gap_s=(200.0, 2000.0))
    X, P, nis, flag, _ = run_engine(2, offsets, t, ze, zn, w, c, q, smooth=True)
    spec = get_model("cv")
    assert np.isfinite(X).all() and np.isfinite(P).all()
    for b in range(20):
        s, g, ref = run_reference(spec, b, offsets, t, ze, zn, w, c, q, smooth=True)
        np.testing.assert_array_equal(g.flag, flag[s])
        np.testing.assert_allclose(X[s][:, 0, 0], ref.x[:, 0], rtol=0, atol=1e-6 * (np.abs(ref.x).max() + 1))


@pytest.mark.parametrize("q, turn, lag_m", [(0.5, "manoeuvre", 1.0), (0.05, "manoeuvre", 1.5), (0.0005, "reset", 15.0)])
def test_a_turn_is_followed_not_lost(q, turn, lag_m):
    """A 90 degree turn in 6 s at 10 m/s: with q = 0.5 the fix the nominal gate refuses passes as a
    manoeuvre (confirmed by the next fix); with q ten times too small it passes as a sharp manoeuvre
    (100 q); with q a thousand times too small the fixes are refused but the filter restarts from them
    after three; either way the track stays on the fixes (0.5 m noise), within lag_m at the turn."""
    t = np.arange(40.0)
    heading = np.cumsum(np.where((t >= 20) & (t < 26), np.radians(15.0), 0.0))
    e, n = np.cumsum(10 * np.sin(heading)), np.cumsum(10 * np.cos(heading))
    X, _, _, flag, stats = run_engine(2, np.array([0, 40], dtype=np.int64), t, e, n, np.full(40, 0.25),
                                      np.ones(1), np.full(1, q), False)
    names = np.array(FLAGS)[flag]
    err = np.hypot(X[:, 0, 0] - e, X[:, 1, 0] - n)
    assert turn in names[20:30]
    if turn == "manoeuvre":
        assert stats[0, 2] == 0 and stats[0, 3] == 0 and err.max() < lag_m
    else:
        assert stats[0, 3] >= 1 and err[30:].max() < 0.5 and err.max() < lag_m
