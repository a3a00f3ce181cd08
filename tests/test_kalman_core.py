"""The one compiled Kalman predict/update (mptrack._core.kalman) against the readable NumPy reference
:func:`mptrack.linear.kalman_step`, and the documented exceptions (the n = 2, m = 1 time blocks of the
batch engine, the tracking engine's rank-one update) against the core, on random models with NaN gaps."""

import numpy as np
import pytest

from mptrack._core import kalman as core
from mptrack.batch import kalman_filter as batch_kalman_filter
from mptrack.batch import steady_state_filter as batch_steady_state_filter
from mptrack.linear import kalman_step
from mptrack.models import LinearGaussianModel
from mptrack.riccati import steady_state


def _spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T + n * np.eye(n))


def _model(rng, n, m):
    F = np.eye(n) + 0.3 * rng.normal(size=(n, n)) / n
    return F, rng.normal(size=(m, n)), _spd(rng, n, 0.1), _spd(rng, m)


def _gapped(rng, T, m, x_dim=1.0):
    z = x_dim * rng.normal(size=(T, m))
    z[rng.random((T, m)) < 0.25] = np.nan
    z[rng.random(T) < 0.1] = np.nan                       # whole rows missing: predict only
    return z


def _core_run(F, H, Q, R, z, x0, P0, joseph):
    """The KF driven step by step through the core (predict, update, record)."""
    T, m = z.shape
    n = F.shape[0]
    x, P = x0.copy(), P0.copy()
    ws = core.workspace(n, m)
    periods = np.zeros(m)
    nus, Ss, nis = np.full((T, m), np.nan), np.full((T, m, m), np.nan), np.full(T, np.nan)
    xs, Ps, lls = np.empty((T, n)), np.empty((T, n, n)), np.empty(T)
    for k in range(T):
        core.predict(F, Q, x, P, ws)
        status, lls[k] = core.update(x, P, H, H @ x, R, z, k, periods, joseph, ws)
        assert status == core.OK
        core.record_update(ws, z, k, nus, Ss, nis, k)
        xs[k], Ps[k] = x, P
    return xs, Ps, lls, nus, Ss, nis


@pytest.mark.parametrize("joseph", [False, True])
@pytest.mark.parametrize("n, m", [(1, 1), (2, 1), (3, 2), (4, 3)])
def test_core_equals_kalman_step(n, m, joseph):
    rng = np.random.default_rng(100 * n + 10 * m + joseph)
    F, H, Q, R = _model(rng, n, m)
    z = _gapped(rng, 40, m)
    x0, P0 = rng.normal(size=n), _spd(rng, n)
    xs, Ps, lls, nus, Ss, nis = _core_run(F, H, Q, R, z, x0, P0, joseph)
    x, P = x0, P0
    for k in range(z.shape[0]):
        x, P, _, _, ll, nu, S = kalman_step(F, H, Q, R, x, P, z[k], joseph, innovation=True)
        np.testing.assert_allclose(xs[k], x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Ps[k], P, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(lls[k], ll, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(nus[k], nu, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Ss[k], S, rtol=1e-10, atol=1e-12)
        ok = ~np.isnan(z[k])
        if ok.any():
            v = nu[ok]
            np.testing.assert_allclose(nis[k], v @ np.linalg.solve(S[np.ix_(ok, ok)], v), rtol=1e-10)
        else:
            assert np.isnan(nis[k])


def test_unscented_update_of_a_linear_measurement_is_the_kalman_update():
    """For h(x) = H x the unscented transform is exact: the UKF's gain step with C = P_xz gives the KF update."""
    rng = np.random.default_rng(7)
    n, m = 3, 2
    _, H, _, R = _model(rng, n, m)
    x, P = rng.normal(size=n), _spd(rng, n)
    kappa = 1.0
    c = n + kappa
    Wm = np.full(2 * n + 1, 0.5 / c)
    Wm[0] = kappa / c
    L = np.linalg.cholesky(c * P)
    X = np.vstack([x, x + L.T, x - L.T])
    z = np.array([[0.3, np.nan], [0.3, -1.2]])
    for k in range(2):
        nus, Ss, nis = np.full((2, m), np.nan), np.full((2, m, m), np.nan), np.full(2, np.nan)
        status, xu, Pu, ll = core.unscented_update(x, P, X, X @ H.T, Wm, Wm, R, z, k, np.zeros(m), nus, Ss, nis, k)
        assert status == core.OK
        xr, Pr, _, _, llr = kalman_step(np.eye(n), H, np.zeros((n, n)), R, x, P, z[k], predict=False)
        np.testing.assert_allclose(xu, xr, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(Pu, Pr, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(ll, llr, rtol=1e-10)


def test_update_reports_a_covariance_without_cholesky_factor():
    ws = core.workspace(2, 1)
    x, P = np.zeros(2), np.zeros((2, 2))
    status, _ = core.update(x, P, np.array([[1.0, 0.0]]), np.zeros(1), np.zeros((1, 1)), np.ones((1, 1)), 0,
                            np.zeros(1), False, ws)
    assert status == core.NOT_PD


def _model_21(rng):
    dt = 1.0
    F = np.array([[1.0, dt], [0.0, 1.0]])
    g = np.array([[0.5 * dt * dt], [dt]])
    return LinearGaussianModel(F, np.array([[1.0, 0.0]]), 0.2 * g @ g.T, np.array([[2.0]]))


def _states(result):
    return np.asarray(getattr(result, "x", result))


@pytest.mark.parametrize("n, m", [(2, 1), (4, 2)])
def test_shared_gain_kf_kernels_equal_the_core(n, m):
    """The batch KF's shared-gain paths -- kf_kernel_blocks (n = 2, m = 1: eight steps as vectors) and
    kf_kernel (any n, m) -- which fall back to the core at a track's first gap, against the KF run by the
    core per track; tracks of different lengths, with NaN gaps (whole rows and single components)."""
    rng = np.random.default_rng(21 + n)
    model = _model_21(rng) if n == 2 else LinearGaussianModel(*_model(rng, n, m))
    B, T = 11, 60
    z = np.cumsum(rng.normal(size=(B, T, m)), axis=1)
    z[2, 30:35] = np.nan
    z[5, 0] = np.nan
    z[9, rng.random(T) < 0.3] = np.nan
    z[7, 20:25, 0] = np.nan
    lengths = np.full(B, T)
    lengths[3] = 17
    x0, P0 = rng.normal(size=(B, n)), np.diag(np.linspace(4.0, 1.0, n))
    out = _states(batch_kalman_filter(model, z, x0, P0, lengths=lengths))
    for b in range(B):
        L = lengths[b]
        xs = _core_run(model.F, model.H, model.Q, model.R, z[b, :L], x0[b], P0, False)[0]
        np.testing.assert_allclose(out[b, :L], xs, rtol=1e-10, atol=1e-10)
        assert np.isnan(out[b, L:]).all()


def test_block_ss_kernel_equals_the_core_from_the_steady_state():
    """ss_kernel_blocks (x = A x + B z, eight steps as vectors) against the KF run by the core from the
    steady-state covariance, which stays there (complete measurements)."""
    rng = np.random.default_rng(22)
    model = _model_21(rng)
    B, T = 9, 50
    z = np.cumsum(rng.normal(size=(B, T, 1)), axis=1)
    x0 = rng.normal(size=(B, 2))
    ss = steady_state(model, "dare")
    out = _states(batch_steady_state_filter(model, z, x0, steady=ss))
    for b in range(B):
        xs = _core_run(model.F, model.H, model.Q, model.R, z[b], x0[b], ss.P_filt, False)[0]
        np.testing.assert_allclose(out[b], xs, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("order", [2, 3])
@pytest.mark.parametrize("slow", [False, True])
def test_tracking_engine_update_equals_the_core(order, slow):
    """The tracking engine's rank-one Joseph-form update of two axes sharing one covariance (a position fix of
    variance r, measuring the position plus the fix error's slow part when there is one) against the core's
    Joseph form on each axis."""
    from mptrack.tracking._chain import update as _update

    rng = np.random.default_rng(order + 10 * slow)
    n = order + slow
    Pp = _spd(rng, n)
    xp = rng.normal(size=(2, n))
    r, ze, zn = 0.7, 1.3, -0.4
    x, P, A, T, k = np.empty((2, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty(n)
    e, S = _update(n, order if slow else -1, xp, Pp, r, ze, zn, x, P, A, T, k)
    H = np.zeros((1, n))
    H[0, 0] = 1.0
    H[0, n - 1] += float(slow)
    nis = 0.0
    for a, za in enumerate((ze, zn)):
        xa, Pa = xp[a].copy(), Pp.copy()
        ws = core.workspace(n, 1)
        status, _ = core.update(xa, Pa, H, H @ xa, np.array([[r]]), np.array([[za]]), 0, np.zeros(1), True, ws)
        assert status == core.OK
        nis += (za - H[0] @ xp[a]) ** 2 / (H[0] @ Pp @ H[0] + r)
        np.testing.assert_allclose(x[a], xa, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(P, Pa, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(e, nis, rtol=1e-12)
    np.testing.assert_allclose(S, H[0] @ Pp @ H[0] + r, rtol=1e-14)


@pytest.mark.parametrize("gap_s", [3600.0, 86400.0, 30 * 86400.0])
def test_tracking_engine_update_keeps_the_fix_variance_after_a_long_gap(gap_s):
    """After a gap the predicted position variance is huge next to the fix's (q dt^3 / 3: 1e10 to 1e19 m^2
    against 1e-6 m^2): the update must leave the fix's variance plus the slow error's, where the standard
    form P - K H P cancels to 0 (the first fix after a 3-day gap had var_east_m2 = 0).  Against exact
    rational arithmetic of the same update."""
    from fractions import Fraction

    from mptrack.tracking._chain import transition
    from mptrack.tracking._chain import update as _update

    q, r, sb2, tau = 1.5, 1e-6, 4.0, 3600.0
    F, Qu = np.zeros((3, 3)), np.zeros((3, 3))
    qb = sb2 * transition(2, 3, gap_s, tau, F, Qu)
    P0 = np.array([[1.0, 0.1, -0.5], [0.1, 0.3, 0.0], [-0.5, 0.0, 2.0]])
    Pp = F @ P0 @ F.T + q * Qu
    Pp[2, 2] += qb
    x, P, A, T, k = np.empty((2, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    _update(3, 2, np.zeros((2, 3)), Pp, r, 1.0, 2.0, x, P, A, T, k)
    h = [1, 0, 1]
    Pf = [[Fraction(v) for v in row] for row in Pp]
    c = [sum(Pf[i][j] * h[j] for j in range(3)) for i in range(3)]
    S = sum(h[i] * c[i] for i in range(3)) + Fraction(r)
    exact = np.array([[float(Pf[i][j] - c[i] * c[j] / S) for j in range(3)] for i in range(3)])
    scale = np.sqrt(np.outer(np.diag(exact), np.diag(exact)))
    np.testing.assert_array_less(np.abs(P - exact) / scale, 1e-9)
    assert P[0, 0] > r and np.all(np.linalg.eigvalsh(P) > 0)
