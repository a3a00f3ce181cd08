"""FEKF and FCS (Bouzera et al. 2017, Tables II and IV): fusion properties (Propositions 1-2),
the exact vs printed covariance (eq. 16), missing ranges, batching and bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.cellular import (
    bouzera_fcs_fis,
    bouzera_fekf_fis,
    ekf_ranges,
    fcs_ranges,
    fcs_ranges_batch,
    fekf_ranges,
    fekf_ranges_batch,
    fuse_local_solutions,
    range_measurement,
)
from mptrack.errors import ParameterError
from mptrack.fuzzy import TakagiSugeno, uniform_partition

STATIONS = np.array([[0.0, 0.0, 0.03], [2.0, 0.0, 0.03], [1.0, 1.7, 0.03]])
Q0 = np.diag([0.02, 0.02, 0.002])
P0 = 1e-3 * np.eye(3)


def _track(T=30, seed=0, sigma=0.001, stations=STATIONS):
    rng = np.random.default_rng(seed)
    t = np.arange(1, T + 1)
    truth = np.stack([0.3 + 0.01 * t, 0.4 + 0.005 * t, np.full(T, 0.0015)], 1)
    z = np.linalg.norm(truth[:, None, :] - stations, axis=-1) + sigma * rng.standard_normal((T, len(stations)))
    return truth, np.abs(z)


def _locals(x, P, stations, d, r):
    h, H = range_measurement(x, stations)
    S = np.einsum("mn,nk,mk->m", H, P, H) + r
    K = (P @ H.T / S).T
    return H, S, K, d - h


@pytest.mark.parametrize("covariance", ["paper", "exact"])
@pytest.mark.parametrize("run", [fekf_ranges, fcs_ranges])
def test_single_station_equals_the_ekf(run, covariance):
    truth, z = _track(T=10)
    st1 = STATIONS[:1]
    ekf = ekf_ranges(z[:, :1], st1, truth[0], P0, Q0, 0.222)
    ours = run(z[:, :1], st1, truth[0], P0, Q0, 0.222, covariance=covariance)
    np.testing.assert_allclose(ours.x, ekf.x, rtol=1e-12)
    np.testing.assert_allclose(ours.P, ekf.P, rtol=1e-9, atol=1e-15)


def test_fusion_is_a_convex_combination_of_local_solutions():
    rng = np.random.default_rng(3)
    x = np.array([0.8, 0.6, 0.0015])
    P = 0.03 * np.eye(3)
    H, S, K, inn = _locals(x, P, STATIONS, rng.uniform(0.5, 1.5, 3), 0.222)
    local = x + K * inn[:, None]
    args = [a[None] for a in (x, P, K, H, inn, S)]
    for y in ([1.0, 1.0, 1.0], [0.0, 1.0, 0.0], [0.2, 0.5, 0.9]):
        y = np.array(y)
        xf, _ = fuse_local_solutions(*args, np.full(3, 0.222), y[None])
        np.testing.assert_allclose(xf[0], (y / y.sum()) @ local)  # eq. 15; y = e_j gives local j
    # scaling all weights does not change the fusion
    a, pa = fuse_local_solutions(*args, np.full(3, 0.222), np.array([[0.2, 0.5, 0.9]]))
    b, pb = fuse_local_solutions(*args, np.full(3, 0.222), np.array([[0.4, 1.0, 1.8]]))
    np.testing.assert_allclose(a, b)
    np.testing.assert_allclose(pa, pb)


def test_exact_covariance_matches_monte_carlo_and_eq16_does_not():
    # linear(ised) measurements, fixed weights: the fused error covariance is known exactly
    rng = np.random.default_rng(7)
    x = np.array([0.8, 0.6, 0.0015])
    P = np.diag([0.05, 0.04, 0.003])
    r = 0.01
    H, S, K, _ = _locals(x, P, STATIONS, np.zeros(3), r)
    y = np.array([0.3, 1.0, 0.6])
    w = y / y.sum()
    N = 200_000
    e0 = rng.multivariate_normal(np.zeros(3), P, size=N)      # X - X^-
    v = np.sqrt(r) * rng.standard_normal((N, 3))
    innov = e0 @ H.T + v                                        # eq. 22
    err = e0 - (innov * w) @ K                                  # X - X_est (eq. 19)
    emp = err.T @ err / N
    args = [a[None] for a in (x, P, K, H, np.zeros(3), S)]
    _, exact = fuse_local_solutions(*args, np.full(3, r), y[None], covariance="exact")
    _, paper = fuse_local_solutions(*args, np.full(3, r), y[None], covariance="paper")
    np.testing.assert_allclose(exact[0], emp, atol=4e-4)
    assert np.abs(paper[0] - emp).max() > 10 * np.abs(exact[0] - emp).max()


def test_fcs_prefers_near_stations():
    f = bouzera_fcs_fis()
    assert f(0.1) > f(0.7) > f(1.4)
    g = bouzera_fekf_fis()
    assert g(0.05, 0.225) > g(1.2, 0.225)  # small innovation, small variance: trusted
    assert g(0.0, 0.22) == pytest.approx(1.0) and g(1.5, 0.22) == pytest.approx(0.0)


def test_any_number_of_stations_and_missing_ranges():
    stations = np.array([[0.0, 0.0, 0.03], [2.0, 0.0, 0.03], [1.0, 1.7, 0.03], [0.0, 1.5, 0.02], [2.2, 1.6, 0.04]])
    truth, z = _track(T=20, stations=stations)
    for run in (fekf_ranges, fcs_ranges):
        res = run(z, stations, truth[0], P0, Q0, 0.222)
        assert np.isfinite(res.x).all()
        assert np.linalg.norm(res.x[-5:] - truth[-5:], axis=1).mean() < 0.2
        zz = z.copy()
        zz[4, 1] = np.nan
        zz[8] = np.nan
        full = run(zz, stations, truth[0], P0, Q0, 0.222)
        head = run(z[:4], stations, truth[0], P0, Q0, 0.222)
        keep = [0, 2, 3, 4]
        step = run(z[4:5, keep], stations[keep], head.x[-1], head.P[-1], Q0, 0.222)
        np.testing.assert_allclose(full.x[4], step.x[0], rtol=1e-12)
        np.testing.assert_allclose(full.x[8], full.x[7])  # all ranges missing: predict only
        np.testing.assert_allclose(full.P[8], full.P[7] + Q0)


def test_batch_equals_single_runs():
    runs = [_track(T=8, seed=s) for s in range(3)]
    z = np.stack([r[1] for r in runs])
    x0 = np.stack([r[0][0] for r in runs])
    for batch_fn, single_fn in ((fekf_ranges_batch, fekf_ranges), (fcs_ranges_batch, fcs_ranges)):
        batch = batch_fn(z, STATIONS, x0, P0, Q0, 0.222)
        for b in range(3):
            np.testing.assert_allclose(batch.x[b], single_fn(z[b], STATIONS, x0[b], P0, Q0, 0.222).x, rtol=1e-12)


def test_custom_fis_and_bad_input():
    truth, z = _track(T=5)
    one = TakagiSugeno((uniform_partition(0, 1, 2),), [1.0, 1.0])
    # constant weights: FCS with equal weights == FEKF with equal weights
    two = TakagiSugeno((uniform_partition(0, 1, 2), uniform_partition(0, 1, 2)), np.ones((2, 2)))
    np.testing.assert_allclose(fcs_ranges(z, STATIONS, truth[0], P0, Q0, 0.222, fis=one).x,
                               fekf_ranges(z, STATIONS, truth[0], P0, Q0, 0.222, fis=two).x)
    with pytest.raises(ParameterError, match="fis"):
        fekf_ranges(z, STATIONS, truth[0], P0, Q0, 0.222, fis=one)
    with pytest.raises(ParameterError, match="R: "):
        fekf_ranges(z, STATIONS, truth[0], P0, Q0, 0.2 * np.eye(3) + 0.01)
    with pytest.raises(ParameterError, match="covariance"):
        fcs_ranges(z, STATIONS, truth[0], P0, Q0, 0.222, covariance="joseph")


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3).filter(lambda y: sum(y) > 1e-3),
       st.integers(0, 1000))
def test_exact_fused_covariance_is_psd_and_estimate_in_hull(y, seed):
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.2, 1.8, 3) * np.array([1, 1, 0.01])
    A = rng.standard_normal((3, 3))
    P = A @ A.T * 0.01 + 1e-4 * np.eye(3)
    H, S, K, inn = _locals(x, P, STATIONS, rng.uniform(0.1, 2.0, 3), 0.05)
    y = np.array(y)
    xf, Pf = fuse_local_solutions(*(a[None] for a in (x, P, K, H, inn, S)), np.full(3, 0.05), y[None],
                                  covariance="exact")
    assert np.linalg.eigvalsh(Pf[0]).min() > -1e-12
    local = x + K * inn[:, None]
    lo, hi = local.min(axis=0) - 1e-12, local.max(axis=0) + 1e-12
    assert np.all((xf[0] >= lo) & (xf[0] <= hi))  # Proposition 2 (inside the bounding box of the hull)


def test_printed_eq16_can_go_indefinite_and_exact_cannot():
    truth, z = _track(T=40)
    Qbig = 5050.0 * np.eye(3)
    paper = fekf_ranges(z, STATIONS, truth[0], P0, Qbig, 0.222, covariance="paper")
    exact = fekf_ranges(z, STATIONS, truth[0], P0, Qbig, 0.222)
    assert np.linalg.eigvalsh(paper.P)[:, 0].min() < 0
    assert np.linalg.eigvalsh(exact.P)[:, 0].min() > -1e-9
    assert np.isfinite(paper.x).all()


def test_indefinite_prediction_raises_instead_of_nan():
    from mptrack.errors import NotPositiveDefiniteError
    from mptrack.cellular import local_solutions

    x = np.array([[0.8, 0.6, 0.0015]])
    P = -np.eye(3)[None]
    with pytest.raises(NotPositiveDefiniteError, match="covariance='exact'"):
        local_solutions(x, P, np.ones((1, 3)), STATIONS, np.full(3, 0.1))
