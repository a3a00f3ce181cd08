"""The tracking filters against the library's reference filters, gating, smoothing, cellular ranges."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.cellular import ekf_ranges, fekf_ranges
from mptrack.errors import ParameterError, UnknownNameError
from mptrack.io import LocalFrame, iter_tracks
from mptrack.linear import kalman_filter, kalman_filter_irregular, rts_smoother
from mptrack.result import FilterResult
from mptrack.models import (
    constant_acceleration_continuous,
    constant_velocity_continuous,
    discretize_intervals,
    van_loan,
)
from mptrack.radio import arfcn_to_frequency, path_loss
from mptrack.radio import TA_STEP_M, band_of_arfcn
from mptrack.tracking import (TrackOptions, get_cell_method, get_model, kalman_filter_gated, nis_threshold, ranges_km,
                              rts_smoother_gated, simulate, track_cells, track_fixes)

GPX = Path(__file__).parents[1] / "data" / "around-visnjan-with-car.gpx"


def cv_data(T=40, seed=0, irregular=False):
    rng = np.random.default_rng(seed)
    model = constant_velocity_continuous(0.3, axes=2, sigma_r2=4.0)
    dts = rng.uniform(0.2, 3.0, T) if irregular else np.full(T, 1.0)
    t = 10.0 + np.cumsum(dts)
    z = rng.normal(0.0, 2.0, (T, 2)) + np.column_stack([3.0 * t, -1.0 * t])
    x0 = np.array([30.0, 3.0, -10.0, -1.0])
    return model, t, z, x0, np.diag([25.0, 4.0, 25.0, 4.0])


def test_nis_gate_is_the_chi_square_quantile():
    assert nis_threshold(0.999, 2) == pytest.approx(13.815510557964274)
    assert nis_threshold(0.99, 1) == pytest.approx(6.6348966010212145)
    with pytest.raises(ParameterError, match="^probability"):   # the argument's name (it said gate_probability)
        nis_threshold(1.0, 2)


@settings(max_examples=25, deadline=None)
@given(dt=st.floats(1e-3, 100.0), q=st.floats(1e-3, 10.0))
def test_closed_series_transitions_equal_van_loan(dt, q):
    for model in (constant_velocity_continuous(q, axes=2), constant_acceleration_continuous(q, axes=1)):
        F, Q = discretize_intervals(model, np.array([dt]))
        F1, Q1 = van_loan(model.Phi, model.L, model.Qc, dt)
        np.testing.assert_allclose(F[0], F1, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Q[0], Q1, rtol=1e-9, atol=1e-12 * np.abs(Q1).max())


def test_ungated_regular_equals_the_reference_kalman_filter():
    model, t, z, x0, P0 = cv_data()
    g = kalman_filter_gated(model, t, z, x0, P0, t0=t[0] - 1.0, gate_probability=None)
    ref = kalman_filter(model.discretize(1.0), z, x0, P0)
    np.testing.assert_allclose(g.x, ref.x, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(g.P, ref.P, rtol=1e-10, atol=1e-10)
    assert g.loglik == pytest.approx(ref.loglik, rel=1e-10)
    sm = rts_smoother_gated(g)
    ref_sm = rts_smoother(model.discretize(1.0), ref)
    np.testing.assert_allclose(sm.x, ref_sm.x, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(sm.P, ref_sm.P, rtol=1e-8, atol=1e-9)


def test_ungated_irregular_equals_kalman_filter_irregular():
    model, t, z, x0, P0 = cv_data(irregular=True)
    z[5] = np.nan
    g = kalman_filter_gated(model, t, z, x0, P0, t0=t[0] - 0.5, gate_probability=None)
    ref = kalman_filter_irregular(model, t, z, x0, P0, t0=t[0] - 0.5)
    np.testing.assert_allclose(g.x, ref.x, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(g.P, ref.P, rtol=1e-10, atol=1e-10)
    assert g.flag[5] == 2 and np.isnan(g.nis[5])
    sm = rts_smoother_gated(g)
    assert np.all(np.linalg.eigvalsh(g.P - sm.P) > -1e-9)  # smoothing never adds uncertainty


def test_gate_rejects_an_outlier_exactly_like_a_missing_measurement():
    model, t, z, x0, P0 = cv_data(irregular=True, seed=3)
    z_out = z.copy()
    z_out[12] += [80.0, -60.0]
    g = kalman_filter_gated(model, t, z_out, x0, P0, t0=t[0] - 1.0)
    z_nan = z.copy()
    z_nan[12] = np.nan
    ref = kalman_filter_irregular(model, t, z_nan, x0, P0, t0=t[0] - 1.0)
    assert g.flag[12] == 1 and g.nis[12] > nis_threshold(0.999, 2)
    assert np.count_nonzero(g.flag == 1) == 1
    np.testing.assert_allclose(g.x, ref.x, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("case", ["manoeuvre", "candidate turned outlier"])
def test_gated_result_records_the_innovation_its_gate_decided_on(case):
    """A GatedResult is a FilterResult; innovation and S are those of each fix's NIS: the nominal
    prediction's, and at a manoeuvre (flag 5) the manoeuvre hypothesis's (process noise x factor, or x factor^2
    for a sharp one), whose Q the result records; a manoeuvre candidate that the next fix turns into an
    outlier gets its nominal values back."""
    rng = np.random.default_rng(3)
    model = constant_velocity_continuous(0.3, axes=2, sigma_r2=4.0)
    t = 10.0 + np.arange(1.0, 41.0)
    z = rng.normal(0.0, 2.0, (40, 2)) + np.column_stack([3.0 * t, -1.0 * t])
    if case == "manoeuvre":
        z[10] += [40.0, 0.0]        # an outlier outside both gates
        z[25:] += [0.0, 15.0]       # a jump the manoeuvre hypothesis follows
        factor, row, flag = 30.0, 25, 5
    else:
        z[10] += [15.0, 0.0]        # inside the manoeuvre gate, and the next fix says: outlier
        factor, row, flag = 100.0, 10, 1
    g = kalman_filter_gated(model, t, z, np.array([30.0, 3.0, -10.0, -1.0]), np.diag([25.0, 4.0, 25.0, 4.0]),
                            manoeuvre_factor=factor)
    assert isinstance(g, FilterResult) and g.method == "KF-gated"
    assert g.flag[10] == 1 and g.flag[row] == flag
    with pytest.warns(DeprecationWarning, match="GatedResult.result"):
        assert g.result is g
    H, R = model.H, model.R
    # the process noise each step used: the model's, at a manoeuvre the manoeuvre's (factor or factor^2 times)
    Q = discretize_intervals(model, np.diff(np.r_[t[0], t]))[1]
    for k in range(len(t)):
        levels = [g.Q[k] / f for f in ((factor, factor ** 2) if g.flag[k] == 5 else (1.0,))]
        assert any(np.allclose(lev, Q[k], rtol=1e-12, atol=0) for lev in levels), k
    S_m = H @ (g.P_pred[row] + (g.Q[row] - Q[row] if flag == 5 else (factor - 1.0) * Q[row])) @ H.T + R
    nu = g.innovation[row]
    assert nu @ np.linalg.solve(S_m, nu) <= nis_threshold(0.999, 2)   # it was a manoeuvre candidate
    for k in range(len(t)):
        inflate = g.Q[k] - Q[k]
        np.testing.assert_allclose(g.innovation[k], z[k] - H @ g.x_pred[k], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(g.S[k], H @ (g.P_pred[k] + inflate) @ H.T + R, rtol=1e-12)
        nu = g.innovation[k]
        assert g.nis[k] == pytest.approx(nu @ np.linalg.solve(g.S[k], nu), rel=1e-10)


def test_consecutive_consistent_rejections_reset_the_track():
    model, t, z, x0, P0 = cv_data(T=30, seed=4)
    z[15:] += 500.0  # the terminal "jumps": a gate alone would lose it for ever
    g = kalman_filter_gated(model, t, z, x0, P0, max_rejections=3)
    # the restart at the run's last fix; its earlier fixes take the restart state predicted back
    assert g.flag[15:18].tolist() == [3, 3, 3]
    assert np.all(g.flag[18:] == 0)
    np.testing.assert_allclose(g.x[15:17][:, [0, 2]], z[15:17], atol=6.0)
    np.testing.assert_allclose(g.x[17, [0, 2]], z[17], atol=6.0)  # a line through 3 noisy fixes
    np.testing.assert_allclose(g.x[17, [1, 3]], [3.0, -1.0], atol=4.0)


def test_scattered_outliers_never_reset_the_track():
    model, t, z, x0, P0 = cv_data(T=30, seed=5)
    rng = np.random.default_rng(1)
    z[10:16] += rng.uniform(-400, 400, (6, 2))  # six wild fixes in a row, pointing nowhere in particular
    g = kalman_filter_gated(model, t, z, x0, P0, max_rejections=3)
    assert np.all(g.flag[10:16] == 1) and not np.any(g.flag == 3)
    assert np.all(g.flag[16:] == 0)


def test_nis_is_chi_square_for_the_true_model():
    rng = np.random.default_rng(7)
    model = constant_velocity_continuous(0.5, axes=2, sigma_r2=9.0)
    t = np.cumsum(rng.uniform(0.5, 4.0, 800))
    F, Q = discretize_intervals(model, np.diff(np.r_[0.0, t]))
    x = np.zeros(4)
    z = np.empty((len(t), 2))
    for k in range(len(t)):
        x = F[k] @ x + rng.multivariate_normal(np.zeros(4), Q[k])
        z[k] = x[[0, 2]] + rng.normal(0, 3.0, 2)
    g = kalman_filter_gated(model, t, z, np.zeros(4), np.eye(4), t0=0.0, gate_probability=None)
    assert 1.85 < np.mean(g.nis) < 2.15  # E[NIS] = 2; 800 samples, sd of the mean ~ 0.07


def test_bad_inputs_are_named():
    model, t, z, x0, P0 = cv_data()
    with pytest.raises(ParameterError, match="times"):
        kalman_filter_gated(model, t[::-1], z, x0, P0)
    with pytest.raises(ParameterError, match="model"):
        kalman_filter_gated(model.discretize(1.0), t, z, x0, P0)
    with pytest.raises(UnknownNameError, match="model"):
        get_model("ctrv")
    with pytest.raises(UnknownNameError, match="method"):
        get_cell_method("ukf")
    with pytest.raises(UnknownNameError, match="filter"):
        TrackOptions(filter="pf")
    with pytest.raises(ParameterError, match="sigma_m"):
        TrackOptions(sigma_m=-1.0)


@pytest.mark.parametrize("name", ["kf", "lf", "sskf"])
@pytest.mark.parametrize("smooth", [False, True])
def test_real_trace_every_filter_follows_the_fixes(name, smooth):
    (tid, rows), = iter_tracks(GPX)
    out = track_fixes(tid, rows, TrackOptions(filter=name, smooth=smooth, q=2.0))
    used = out["flag"] == "update"
    resid = np.hypot(out["east_m"] - out["meas_east_m"], out["north_m"] - out["meas_north_m"])[used]
    assert np.median(resid) < 10.0
    assert np.all(np.isfinite(out[["lat", "lon", "ell_major_m"]].to_numpy()))
    assert (out["ell_major_m"] >= out["ell_minor_m"]).all()
    if name == "kf":
        assert len(out) == 104 and out["time"].iloc[0] == pd.Timestamp("2020-12-18T06:15:50Z")
        assert out["gap"].sum() == np.count_nonzero(np.diff(rows["t"]) > 30.0) == 3  # stops of 35-49 s


def test_track_fixes_equals_the_library_filter_on_the_same_data():
    """The per-track reference is the library's gated filter started at the first fix: the first fix
    sets the position (variance sigma^2, velocity 0 +- 30 m/s) and is not used a second time."""
    (tid, rows), = iter_tracks(GPX)
    opts = TrackOptions(q=2.0, sigma_m=5.0)
    out = track_fixes(tid, rows, opts)
    frame = LocalFrame.at(rows["lat"], rows["lon"])
    e, n = frame.to_enu(rows["lat"].to_numpy(), rows["lon"].to_numpy())
    model = get_model("cv").build(2.0, 25.0)
    x0 = np.array([e[0], 0.0, n[0], 0.0])
    P0 = np.diag([25.0, 900.0, 25.0, 900.0])
    t = rows["t"].to_numpy()
    g = kalman_filter_gated(model, t[1:], np.column_stack([e, n])[1:], x0, P0, t0=t[0])
    np.testing.assert_allclose(out["east_m"].iloc[1:], g.x[:, 0], atol=1e-9)
    np.testing.assert_allclose(out["var_north_m2"].iloc[1:], g.P[:, 2, 2], rtol=1e-12)
    assert out["flag"].iloc[0] == "init" and np.isnan(out["nis"].iloc[0])
    assert out["east_m"].iloc[0] == e[0] and out["var_east_m2"].iloc[0] == 25.0
    lat, lon = frame.to_geodetic(g.x[:, 0], g.x[:, 2])
    np.testing.assert_allclose(out["lat"].iloc[1:], lat, atol=1e-12)


# ---- cellular -----------------------------------------------------------------------------------------

def test_arfcn_bands():
    assert band_of_arfcn(30) == "E-GSM" and band_of_arfcn(1000) == "E-GSM"
    assert band_of_arfcn(190) == "GSM850" and band_of_arfcn(700) == "DCS1800"


def test_ranges_from_range_ta_and_rss():
    cells = pd.DataFrame({"height_m": [30.0], "power_dbm": [43.0], "arfcn": [700.0]}, index=["c"])
    d_true = np.array([0.3, 1.2, 2.5])
    f = arfcn_to_frequency(700, "DCS1800")
    rss = 43.0 - path_loss(d_true, "cost231-wi-nlos", frequency_mhz=f, h_base_m=30.0)
    rows = pd.DataFrame({"cell_id": ["c"] * 5, "range_m": [150.0, np.nan, np.nan, np.nan, np.nan],
                         "ta": [np.nan, 2, np.nan, np.nan, np.nan], "rss_dbm": [np.nan, -80.0, *rss]})
    r = ranges_km(rows, cells)
    assert r[0] == 0.15 and r[1] == pytest.approx(2.5 * TA_STEP_M / 1e3)
    np.testing.assert_allclose(r[2:], d_true, rtol=1e-9)


@pytest.mark.parametrize("method,fn", [("ekf", ekf_ranges), ("fekf", fekf_ranges)])
def test_track_cells_equals_the_nonlinear_filter(method, fn):
    log, cells = simulate("urban-3bts", 1, np.random.default_rng(2), duration_s=60)
    cells.index = [f"{r.mcc}-{r.net}-{r.area}-{r.cell}" for r in cells.itertuples()]
    _, secs = __import__("mptrack.io._schema", fromlist=["_parse_time"])._parse_time(log["time"])
    rows = log.assign(t=secs, row=np.arange(1, len(log) + 1))
    out = track_cells("sim0001", rows, cells, TrackOptions(method=method))
    ids = list(pd.unique(rows["cell_id"]))
    frame = LocalFrame(cells.loc[ids, "lat"].mean(), cells.loc[ids, "lon"].mean())
    se, sn = frame.to_enu(cells.loc[ids, "lat"].to_numpy(), cells.loc[ids, "lon"].to_numpy())
    stations = np.column_stack([se, sn]) / 1e3
    z = ranges_km(rows, cells).reshape(-1, 3)
    ref = fn(z, stations, stations.mean(axis=0), np.eye(2), 0.02 * np.eye(2), 0.222)
    np.testing.assert_allclose(out[["east_m", "north_m"]].to_numpy(), ref.x * 1e3, rtol=1e-12, atol=1e-9)
    assert out["nis_dof"].eq(3).all() and np.isfinite(out["nis"]).all()
    # the estimate is a real improvement on the prior (cell centroid): within the 1 km cell circle
    tl = log.drop_duplicates("time")
    te, tn = frame.to_enu(tl["true_lat"].to_numpy(), tl["true_lon"].to_numpy())
    err = np.hypot(out["east_m"] - te, out["north_m"] - tn)
    assert np.sqrt(np.mean(err ** 2)) < 400.0


def test_cellular_constant_velocity_tracks_position_and_speed():
    """--motion cv on cells: the [x, vx, y, vy] state is read back as such (a state-order mix-up gave a
    206 m/s median speed for a 10 m/s drive) and the default process noise beats the random walk."""
    import mptrack

    log, cells = simulate("urban-3bts", 6, np.random.default_rng(5), duration_s=300)
    cells.index = [f"{r.mcc}-{r.net}-{r.area}-{r.cell}" for r in cells.itertuples()]
    truth = log.drop_duplicates(["track_id", "time"]).sort_values(["track_id", "time"], kind="stable")
    frame = LocalFrame(truth["true_lat"].mean(), truth["true_lon"].mean())
    te, tn = frame.to_enu(truth["true_lat"].to_numpy(), truth["true_lon"].to_numpy())
    stamps = pd.to_datetime(truth["time"])
    t = (stamps - stamps.iloc[0]).dt.total_seconds().to_numpy()
    same = (truth["track_id"].to_numpy()[1:] == truth["track_id"].to_numpy()[:-1])
    true_speed = np.median(np.hypot(np.diff(te), np.diff(tn))[same] / np.diff(t)[same])
    rmse = {}
    for motion in ("random-walk", "cv"):
        out = mptrack.track(log, cells=cells, method="ekf", motion=motion)
        assert len(out) == len(truth)
        oe, on = frame.to_enu(out["lat"].to_numpy(), out["lon"].to_numpy())
        rmse[motion] = pd.Series((oe - te) ** 2 + (on - tn) ** 2).groupby(truth["track_id"].to_numpy()).mean()
    speed = np.median(np.hypot(out["vel_east_mps"], out["vel_north_mps"]))
    assert 0.5 * true_speed < speed < 2.0 * true_speed
    assert (rmse["cv"] < rmse["random-walk"]).sum() >= 4      # of 6 tracks
