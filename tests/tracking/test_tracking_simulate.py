"""The vectorised simulator: truth against a per-step reference, statistics of the draws, determinism,
round trips through the readers, parameter validation and the ``simulate`` command's options."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import mptrack.tracking._simulate as sim
from mptrack.errors import ParameterError, UnknownNameError
from mptrack.io import MEASUREMENTS, LocalFrame, read_table, write_table
from mptrack.radio import arfcn_to_frequency, path_loss
from mptrack.tracking import simulate
from mptrack.cli import app
from mptrack.tracking._simulate import ORIGIN, Intervals, cv_noise_factor, cv_states, simulate_chunks

GPX = Path(__file__).parents[1] / "data" / "around-visnjan-with-car.gpx"
FRAME = LocalFrame(*ORIGIN)


def enu(df, prefix=""):
    return np.column_stack(FRAME.to_enu(df[prefix + "lat"].to_numpy(), df[prefix + "lon"].to_numpy()))


def reference_states(dt, offsets, v0, z, q):
    """x_k = F(dt) x_{k-1} + chol(Q(dt)) z_k per axis, one step at a time (numpy's Cholesky)."""
    pos, vel = np.zeros((len(dt), 2)), np.zeros((len(dt), 2))
    for b in range(len(offsets) - 1):
        x = np.array([[0.0, v0[b, a]] for a in range(2)])  # (axis, [p, v])
        for k in range(offsets[b], offsets[b + 1]):
            if k > offsets[b]:
                h = dt[k]
                F = np.array([[1.0, h], [0.0, 1.0]])
                L = np.linalg.cholesky(q * np.array([[h ** 3 / 3, h ** 2 / 2], [h ** 2 / 2, h]]))
                x = np.array([F @ x[a] + L @ z[k, a] for a in range(2)])
            pos[k], vel[k] = x[:, 0], x[:, 1]
    return pos, vel


# ---- truth -----------------------------------------------------------------------------------------

def test_closed_form_cholesky():
    for h in (0.001, 0.2, 1.0, 7.5, 60.0):
        Q = 0.7 * np.array([[h ** 3 / 3, h ** 2 / 2], [h ** 2 / 2, h]])
        l11, l21, l22 = cv_noise_factor(h, 0.7)
        np.testing.assert_allclose([[l11, 0], [l21, l22]], np.linalg.cholesky(Q), rtol=1e-12)


def test_vectorised_truth_equals_the_per_step_reference():
    """Same draws -> the same states, also for the last tracks of a long chunk (segment sums restart)."""
    rng = np.random.default_rng(7)
    counts = rng.integers(1, 60, size=400)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    dt = rng.uniform(0.1, 20.0, size=offsets[-1])
    dt[offsets[:-1]] = 0.0
    v0 = rng.normal(0.0, 15.0, size=(len(counts), 2))
    z = rng.standard_normal((offsets[-1], 2, 2))
    pos, vel = cv_states(dt, offsets, v0, z, 0.5)
    rows = np.r_[offsets[0]:offsets[3], offsets[-4]:offsets[-1]]  # three tracks at each end
    keep = np.r_[0, 1, 2, len(counts) - 3, len(counts) - 2, len(counts) - 1]
    sub = np.concatenate([[0], np.cumsum(counts[keep])])
    ref_pos, ref_vel = reference_states(dt[rows], sub, v0[keep], z[rows], 0.5)
    np.testing.assert_allclose(pos[rows], ref_pos, rtol=0, atol=1e-9)
    np.testing.assert_allclose(vel[rows], ref_vel, rtol=0, atol=1e-9)


def test_simulated_truth_is_the_reference_with_the_same_draws():
    """The scenario's truth = the per-step reference run on the simulator's own draws, in order:
    the fix times, the headings, then the process noise."""
    interval = Intervals.exponential(3.0, 0.5)
    truth = sim._simulated_truth(np.random.default_rng(3), 0, 4, 120.0, interval, 0.8, 12.0)
    rng = np.random.default_rng(3)
    offsets, rel_ms = sim._fix_times_ms(rng, 4, 120_000, interval)
    heading = rng.uniform(0, 2 * np.pi, size=4)
    z = rng.standard_normal((len(rel_ms), 2, 2))
    dt = np.diff(rel_ms, prepend=0) / 1e3
    dt[offsets[:-1]] = 0.0
    ref, _ = reference_states(dt, offsets, 12.0 * np.column_stack([np.sin(heading), np.cos(heading)]), z, 0.8)
    np.testing.assert_array_equal(truth.offsets, offsets)
    np.testing.assert_allclose(np.column_stack([truth.east, truth.north]), ref, rtol=0, atol=1e-9)
    assert (truth.time_ms - np.repeat(sim._EPOCH_MS + 3_600_000 * np.arange(4), np.diff(offsets)) == rel_ms).all()


def test_velocity_and_position_increments_have_the_exact_discrete_covariance():
    q = 0.5
    rng = np.random.default_rng(11)
    offsets = np.array([0, 40_000])
    dt = rng.uniform(0.2, 5.0, size=40_000)
    dt[0] = 0.0
    pos, vel = cv_states(dt, offsets, np.zeros((1, 2)), rng.standard_normal((40_000, 2, 2)), q)
    h = dt[1:, None]
    dv = np.diff(vel, axis=0)
    wp = np.diff(pos, axis=0) - vel[:-1] * h
    assert np.var(dv / np.sqrt(h)) == pytest.approx(q, rel=0.02)  # Var(dv) = q dt
    assert np.var(wp / np.sqrt(h ** 3 / 3)) == pytest.approx(q, rel=0.02)  # Var(w_p) = q dt^3 / 3
    corr = np.corrcoef((wp / np.sqrt(h ** 3)).ravel(), (dv / np.sqrt(h)).ravel())[0, 1]
    assert corr == pytest.approx(np.sqrt(3) / 2, abs=0.01)  # Cov = q dt^2 / 2


def test_noise_free_straight_lines_at_the_start_speed():
    log, _ = simulate("gps", 3, np.random.default_rng(0), duration_s=30, q=0.0, speed_mps=7.0, sigma_m=0.0,
                      outlier_rate=0.0, interval="uniform:0.5:1.5")
    np.testing.assert_array_equal(log[["lat", "lon"]].to_numpy(), log[["true_lat", "true_lon"]].to_numpy())
    for _, track in log.groupby("track_id"):
        xy = enu(track, "true_")
        t = track["time"].astype("int64").to_numpy() / 1e3  # ms
        np.testing.assert_allclose(np.hypot(*(xy - xy[0]).T), 7.0 * (t - t[0]), atol=1e-6)
        np.testing.assert_allclose(xy[0], 0.0, atol=1e-6)  # every track starts at the origin


# ---- measurements ----------------------------------------------------------------------------------

def test_fix_noise_and_outliers():
    log, _ = simulate("gps", 100, np.random.default_rng(1), duration_s=300, sigma_m=3.0, outlier_rate=0.1)
    err = enu(log) - enu(log, "true_")
    out = log["is_outlier"].to_numpy()
    n = len(log)
    assert abs(out.mean() - 0.1) < 4 * np.sqrt(0.1 * 0.9 / n)
    assert np.std(err[~out], axis=0) == pytest.approx([3.0, 3.0], rel=0.03)
    assert (log["accuracy_m"] == 3.0).all()
    d = np.hypot(*err[out].T)
    assert d.min() > 50.0 - 5 * 3.0 and d.max() < 150.0 + 5 * 3.0


@pytest.mark.parametrize("spec,lo,hi", [("exp:2:0.2", 0.2, np.inf), ("uniform:0.5:1.5", 0.5, 1.5), ("1", 1.0, 1.0)])
def test_intervals_within_their_bounds(spec, lo, hi):
    interval = Intervals.parse(spec)
    log, _ = simulate("gps", 40, np.random.default_rng(2), duration_s=200, interval=spec)
    t = log["time"].astype("int64").to_numpy() / 1e3
    ids = log["track_id"].to_numpy()
    first = np.r_[True, ids[1:] != ids[:-1]]
    starts, ends = np.flatnonzero(first), np.r_[np.flatnonzero(first)[1:] - 1, len(t) - 1]
    dt = np.diff(t)[~first[1:]]  # within tracks
    assert dt.min() >= lo - 5e-4 and dt.max() <= hi + 5e-4  # intervals are whole ms
    assert dt.mean() == pytest.approx(interval.mean(), rel=0.03)
    assert len(starts) == 40 and (t[ends] - t[starts] <= 200.0).all()
    assert (np.diff(t[starts]) == 3600.0).all()  # track i starts i hours after the first
    if spec == "1":
        assert len(log) == 40 * 201


def test_urban_3bts_rss_follows_the_path_loss_of_each_tracks_stations():
    log, cells = simulate("urban-3bts", 5, np.random.default_rng(4), duration_s=120)
    assert len(log) == 5 * 121 * 3 and len(cells) == 15 and log["cell_id"].nunique() == 15
    key = cells.assign(cell_id=[f"{r.mcc}-{r.net}-{r.area}-{r.cell}" for r in cells.itertuples()])
    st = log.merge(key[["cell_id", "lat", "lon"]], on="cell_id", suffixes=("", "_cell"))
    d = np.hypot(*(enu(st, "true_") - np.column_stack(FRAME.to_enu(st["lat"].to_numpy(),
                                                                   st["lon"].to_numpy()))).T)
    np.testing.assert_allclose(d, st["true_range_m"], rtol=1e-9)
    assert (st.groupby("track_id")["cell_id"].nunique() == 3).all()  # each track hears its own three cells
    loss = path_loss(np.clip(d / 1e3, 0.02, 5.0), "cost231-wi-nlos",
                     frequency_mhz=float(arfcn_to_frequency(700, "DCS1800")), h_base_m=30.0, on_invalid="ignore")
    assert np.std(st["rss_dbm"] - (43.0 - loss)) == pytest.approx(4.0, rel=0.05)


def test_along_tracks_in_their_own_frames(tmp_path):
    """Two real tracks 10 degrees apart: truth is the file's positions and times, noise is metres in each
    track's own frame."""
    base, _ = simulate("gps", 2, np.random.default_rng(5), duration_s=600, sigma_m=0.0, outlier_rate=0.0)
    base.loc[base["track_id"] == "sim0002", "lat"] += 10.0
    path = write_table(base[["track_id", "time", "lat", "lon"]], tmp_path / "real.parquet")
    log, _ = simulate("gps", 1, np.random.default_rng(6), along=path, sigma_m=2.0, outlier_rate=0.0)
    np.testing.assert_allclose(log[["true_lat", "true_lon"]].to_numpy(), base[["lat", "lon"]].to_numpy(),
                               rtol=0, atol=1e-12)
    assert (log["time"] == base["time"]).all()
    for _, track in log.groupby("track_id"):
        frame = LocalFrame(track["true_lat"].iloc[0], track["true_lon"].iloc[0])
        err = np.column_stack(frame.to_enu(track["lat"], track["lon"])) - \
            np.column_stack(frame.to_enu(track["true_lat"], track["true_lon"]))
        assert np.std(err, axis=0) == pytest.approx([2.0, 2.0], rel=0.1)


# ---- determinism, chunks and files ------------------------------------------------------------------

def test_depends_only_on_the_seed_and_chunks_are_the_whole(monkeypatch):
    a, _ = simulate("gps", 30, np.random.default_rng(9), duration_s=60)
    b, _ = simulate("gps", 30, np.random.default_rng(9), duration_s=60)
    pd.testing.assert_frame_equal(a, b)
    c, _ = simulate("gps", 30, np.random.default_rng(10), duration_s=60)
    assert not a.equals(c)
    monkeypatch.setattr(sim, "CHUNK_ROWS", 200)  # many chunks of whole tracks
    chunks = list(simulate_chunks("urban-3bts", 9, np.random.default_rng(1), duration_s=50))
    assert len(chunks) > 2
    whole = pd.concat([log for log, _ in chunks], ignore_index=True)
    again, cells = simulate("urban-3bts", 9, np.random.default_rng(1), duration_s=50)
    pd.testing.assert_frame_equal(whole, again)
    assert cells["area"].tolist() == list(np.repeat(np.arange(100, 109), 3))
    assert whole["track_id"].is_monotonic_increasing and whole["track_id"].nunique() == 9


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_round_trip_through_the_readers(tmp_path, suffix):
    log, _ = simulate("gps", 4, np.random.default_rng(12), duration_s=90)
    path = write_table(log, tmp_path / f"sim{suffix}")
    back = read_table(path)
    assert back["track_id"].tolist() == log["track_id"].tolist()
    assert (back["time"] == log["time"]).all()  # the same instants
    np.testing.assert_allclose(back["t"], log["time"].astype("int64").to_numpy() / 1e3, rtol=0, atol=1e-6)
    for col in ("lat", "lon", "accuracy_m"):
        np.testing.assert_array_equal(back[col], log[col])
    if suffix == ".csv":
        first = path.read_text().splitlines()[1]
        assert first.startswith("sim0001,2024-01-01T00:00:00.000Z,")
    else:
        import pyarrow.parquet as pq

        assert str(pq.read_schema(path).field("time").type) == "timestamp[ms, tz=UTC]"


def test_cellular_round_trip(tmp_path):
    log, _ = simulate("urban-3bts", 2, np.random.default_rng(3), duration_s=20)
    back = read_table(write_table(log, tmp_path / "c.csv"), MEASUREMENTS)
    assert (back["time"] == log["time"]).all()
    np.testing.assert_array_equal(back["rss_dbm"], log["rss_dbm"])


# ---- validation and the command line ---------------------------------------------------------------

@pytest.mark.parametrize("kwargs,match", [
    ({"sigma_m": -1.0}, "sigma_m"), ({"outlier_rate": 1.5}, "outlier_rate"), ({"q": -0.1}, "q"),
    ({"speed_mps": float("nan")}, "speed_mps"), ({"duration_s": 0}, "duration_s"), ({"tracks": 0}, "tracks"),
    ({"interval": "0.0001:1"}, "interval"), ({"interval": "3:1"}, "interval"), ({"interval": "often"}, "interval"),
    ({"interval": "exp:-2"}, "interval"), ({"accuracy_column": "no"}, "accuracy_column"),
])
def test_invalid_parameters(kwargs, match):
    args = {"tracks": 2, **kwargs}
    with pytest.raises(ParameterError, match=match):
        simulate("gps", args.pop("tracks"), np.random.default_rng(0), **args)


def test_along_needs_tracks(tmp_path):
    from mptrack.errors import DataError

    (tmp_path / "empty.csv").write_text("track_id,time,lat,lon\n")
    with pytest.raises(DataError, match="no rows to track: the input is empty or has a header only"):
        simulate("gps", 1, np.random.default_rng(0), along=tmp_path / "empty.csv")


def test_options_of_another_scenario_are_refused():
    with pytest.raises(ParameterError, match="sigma_m: not an option of scenario 'urban-3bts'"):
        simulate("urban-3bts", 1, np.random.default_rng(0), sigma_m=3.0)
    with pytest.raises(UnknownNameError, match="scenario"):
        simulate("rural", 1, np.random.default_rng(0))


def test_cli_options(tmp_path):
    runner = CliRunner()
    out = tmp_path / "s.csv"
    res = runner.invoke(app, ["simulate", "--tracks", "3", "--duration", "20", "--interval", "2", "--sigma", "1",
                              "--outliers", "0", "--q", "0", "--speed", "4", "--no-accuracy", "--seed", "3",
                              "--out", str(out), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout) == {"scenario": "gps", "log": str(out), "rows": 33, "tracks": 3, "seed": 3}
    df = pd.read_csv(out)
    assert "accuracy_m" not in df.columns and not df["is_outlier"].any()
    assert read_table(out)["t"].diff().dropna().isin([2.0, 3600.0 - 20.0]).all()
    for args, option in ((["--sigma", "-1"], "--sigma"), (["--interval", "5:1"], "--interval"),
                         (["--scenario", "urban-3bts", "--outliers", "0.1"], "--outliers"),
                         (["--q", "-1"], "--q")):
        res = runner.invoke(app, ["simulate", "--out", str(tmp_path / "x.parquet"), *args])
        assert res.exit_code == 2 and option in res.stderr, (args, res.output)
    assert not (tmp_path / "x.parquet").exists()
