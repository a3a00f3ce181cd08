"""Automatic noise calibration: unbiased estimates with honest standard errors, a consistent filter,
sensible results on real traces, fallbacks that are flagged (never NaN), and defaults that never make
the tracks worse than the raw fixes."""

import numpy as np
import pandas as pd
import pytest
import scipy.stats

from _data import REAL_TRACES, REAL_TRACK_IDS
from mptrack.bench.tracking import rmse_vs_truth
from mptrack.tracking import Intervals, simulate, track
from mptrack.tracking._columns import FixTable
from mptrack.tracking._noise import NoiseSpec, estimate_noise, fix_weights


def sim(seed, tracks, duration_s, *, sigma=5.0, q=0.5, interval=None, outliers=0.0, accuracy=False):
    log, _ = simulate("gps", tracks, np.random.default_rng(seed), duration_s=duration_s, sigma_m=sigma, q=q,
                      interval=interval, outlier_rate=outliers, accuracy_column=accuracy)
    return log


@pytest.fixture(scope="module")
def fifty_tracks():
    """50 tracks of ~1000 fixes (exponential intervals, mean 2 s), sigma 5 m, q 0.5 m^2/s^3, no outliers."""
    log = sim(12, 50, 2000.0)
    return log, track(log)


def test_estimates_are_unbiased_and_their_standard_errors_match_the_spread(fifty_tracks):
    log, points = fifty_tracks
    tr = points.attrs["tracks"]
    assert len(tr) == 50 and tr["fixes"].min() > 800 and (tr["sigma_source"] == "estimated").all()
    sigma, q = tr["sigma_m"].to_numpy(), tr["q"].to_numpy()
    assert abs(sigma.mean() / 5.0 - 1) < 0.05 and abs(q.mean() / 0.5 - 1) < 0.10
    # each estimate's standard error (observed information) is the size of the spread across tracks
    for est, se in ((sigma, tr["sigma_se_m"]), (q, tr["q_se"])):
        assert 0.7 < est.std(ddof=1) / se.mean() < 1.4
    # and the truth is inside +-2 se for about 95 % of the tracks
    inside = (np.abs(sigma - 5.0) < 2 * tr["sigma_se_m"]) & (np.abs(q - 0.5) < 2 * tr["q_se"])
    assert inside.mean() > 0.85


def test_the_calibrated_filter_is_consistent(fifty_tracks):
    log, points = fifty_tracks
    tr = points.attrs["tracks"]
    assert tr["nis_consistent"].mean() >= 0.9
    used = points["flag"].isin(["update", "manoeuvre"])
    nis = points.loc[used, "nis"].to_numpy()
    lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], 2 * len(nis)) / len(nis)
    assert lo <= nis.mean() <= hi
    est, raw = rmse_vs_truth(points, log)
    assert est < 0.85 * raw


def test_accuracy_column_gets_a_scale_factor():
    """A device that reports accuracy_m = 5 m for fixes with 3 m noise: the scale 0.6 is estimated."""
    log = sim(3, 10, 2000.0, sigma=3.0, accuracy=True).assign(accuracy_m=5.0)
    tr = track(log).attrs["tracks"]
    assert abs(tr["accuracy_scale"].mean() / 0.6 - 1) < 0.05
    assert np.allclose(tr["sigma_m"], tr["accuracy_scale"] * 5.0)


@pytest.mark.parametrize("kind", ["car", "hike", "bike"])
def test_real_traces_calibrate_to_a_consistent_filter(kind):
    points = track(REAL_TRACES[kind])
    tr = points.attrs["tracks"]
    assert set(tr["track_id"]) == set(REAL_TRACK_IDS[kind])
    assert np.isfinite(points[["lat", "lon", "east_m", "var_east_m2"]].to_numpy()).all()
    # mean NIS within [0.5, 2] x its 2 degrees of freedom, few rejections
    assert ((tr["mean_nis"] >= 1.0) & (tr["mean_nis"] <= 4.0)).all(), tr[["mean_nis"]]
    assert (tr["outliers"] + tr["resets"]).sum() <= 0.01 * tr["fixes"].sum()
    # these receivers smooth their output: the white fix noise is (near) nil and the track follows the fixes
    moved = np.hypot(points["east_m"] - points["meas_east_m"], points["north_m"] - points["meas_north_m"])
    assert np.median(moved[points["flag"] == "update"]) < 0.5


def test_short_tracks_share_one_pooled_estimate():
    """300 tracks of ~10 fixes each: none carries its own estimate; together they do."""
    log = sim(8, 300, 20.0)
    tr = track(log).attrs["tracks"]
    assert (tr["sigma_source"] == "pooled").all() and tr["sigma_m"].nunique() == 1
    assert abs(tr["sigma_m"].iloc[0] / 5.0 - 1) < 0.1


def test_given_sigma_or_q_turns_estimation_off_for_that_parameter(fifty_tracks):
    log, _ = fifty_tracks
    log = log[log["track_id"].isin(["sim0001", "sim0002"])]
    tr = track(log, sigma_m=5.0).attrs["tracks"]
    assert (tr["sigma_source"] == "given").all() and (tr["sigma_m"] == 5.0).all()
    assert (tr["q_source"] == "estimated").all() and np.allclose(tr["q"], 0.5, rtol=0.25)
    tr = track(log, q=0.5).attrs["tracks"]
    assert (tr["q_source"] == "given").all() and np.allclose(tr["sigma_m"], 5.0, rtol=0.1)
    tr = track(log, q=0.5, sigma_m=5.0).attrs["tracks"]
    assert (tr[["sigma_source", "q_source"]] == "given").all().all() and tr["sigma_se_m"].isna().all()


def test_one_estimate_per_file():
    log = sim(4, 20, 300.0)
    for chunk_rows in (10 ** 6, 500):  # the whole file in one chunk, or estimated on the first chunk
        tr = track(log, noise="file", chunk_rows=chunk_rows).attrs["tracks"]
        assert tr["sigma_m"].nunique() == 1 and tr["q"].nunique() == 1 and (tr["sigma_source"] == "pooled").all()
        assert abs(tr["sigma_m"].iloc[0] / 5.0 - 1) < 0.1


def _table(t, e, n):
    """A FixTable of one track per list entry (x/y metres)."""
    ids = np.concatenate([[f"t{i}"] * len(x) for i, x in enumerate(t)])
    df = pd.DataFrame({"track_id": ids, "time": np.concatenate(t), "t": np.concatenate(t),
                       "x": np.concatenate(e), "y": np.concatenate(n), "row": np.arange(1, len(ids) + 1)})
    return FixTable.from_frame(df)


def test_tracks_that_cannot_be_calibrated_fall_back_and_are_flagged():
    """Two fixes; every fix the same point; all time stamps equal: stated defaults (or the pool),
    flagged, finite, never NaN."""
    T = np.arange(40.0)
    table = _table([T[:2], T, np.full(40, 7.0)], [T[:2] * 3, np.full(40, 5.0), np.arange(40.0)],
                   [T[:2], np.full(40, -2.0), np.zeros(40)])
    w, has = fix_weights(table, None)
    est = estimate_noise(table, w, has, NoiseSpec(order=2, prior=np.array([0.0, 900.0]), gate=13.8))
    assert np.isfinite(est.c).all() and np.isfinite(est.q).all() and (est.c > 0).all()
    assert (est.source_c != 0).all() and (est.source_q != 0).all()  # none "estimated"
    # through the public API the same tracks are tracked, their noise source reported
    points = track(pd.DataFrame({"track_id": ["a", "a"], "time": [0.0, 1.0], "x": [0.0, 1.0], "y": [0.0, 0.0]}))
    tr = points.attrs["tracks"]
    assert tr["sigma_source"].iloc[0] == "default" and tr["sigma_m"].iloc[0] == 5.0
    assert np.isfinite(points[["east_m", "var_east_m2"]].to_numpy()).all()


@pytest.mark.parametrize("sigma", [1.0, 20.0, 100.0])
@pytest.mark.parametrize("q", [0.01, 10.0])
def test_no_flags_is_close_to_the_oracle_and_never_worse_than_the_fixes(sigma, q):
    """The benchmark's sweep in small (benchmarks/bench_tracking.py runs the full one): intervals 0.5-30 s,
    no flags against the same filter given the true sigma and q."""
    log = sim(int(sigma * 10 + q * 100), 8, 3000.0, sigma=sigma, q=q, interval=Intervals.uniform(0.5, 30.0))
    auto, raw = rmse_vs_truth(track(log), log)
    oracle, _ = rmse_vs_truth(track(log, sigma_m=sigma, q=q), log)
    assert auto <= 1.1 * oracle and auto <= raw
    smooth, _ = rmse_vs_truth(track(log, smooth=True), log)
    smooth_oracle, _ = rmse_vs_truth(track(log, smooth=True, sigma_m=sigma, q=q), log)
    assert smooth <= 1.1 * smooth_oracle and smooth <= raw


def test_advice_names_the_option_and_ignores_tracks_of_a_few_fixes():
    log = sim(6, 3, 600.0)
    advice = track(log, sigma_m=50.0).attrs["summary"]["nis"]["advice"]
    assert len(advice) == 1 and "far below" in advice[0] and "--sigma" in advice[0]
    assert track(log).attrs["summary"]["nis"]["advice"] == []
    # three tracks of two fixes: their mean NIS of one fix is no evidence of anything
    tiny = pd.DataFrame({"track_id": ["a", "a", "b", "b", "c", "c"], "time": [0.0, 1.0] * 3,
                         "x": [0.0, 10.0, 0.0, 10.0, 0.0, 10.0], "y": [0.0, 0.0, 5.0, 5.0, 9.0, 9.0]})
    assert track(tiny, sigma_m=50.0).attrs["summary"]["nis"]["advice"] == []


@pytest.mark.parametrize("accuracy", [False, True])
@pytest.mark.parametrize("sigma", [3.0, 20.0, 60.0])
def test_white_noise_fixes_are_tracked_as_well_as_before_the_slow_error(sigma, accuracy):
    """Simulated fixes with white noise only (the truth has no slow error), no flags: the estimates stay well
    below the fixes' error (RMSE <= 0.85 x the raw fixes'), with or without an accuracy column; a 3 m noise
    without accuracies leaves a slow part of the 5 m default, which must not cost accuracy."""
    log = sim(int(sigma) + 7 * accuracy, 10, 1200.0, sigma=sigma, accuracy=accuracy)
    est, raw = rmse_vs_truth(track(log), log)
    assert est <= 0.85 * raw, (est, raw)
