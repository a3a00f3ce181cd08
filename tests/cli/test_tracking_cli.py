"""End to end: ``track``, ``simulate`` and ``evaluate`` through typer's CliRunner and a real subprocess."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import mptrack.tracking._pipeline as pipeline
from mptrack.errors import ParameterError
from mptrack.io import iter_tracks
from mptrack.runs import PartStore
from mptrack.tracking import TrackOptions, track, track_file, track_fixes
from mptrack.cli import app

GPX = Path(__file__).parents[1] / "data" / "around-visnjan-with-car.gpx"
runner = CliRunner()


def run(*args):
    result = runner.invoke(app, [str(a) for a in args])
    return result


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A small simulated GPS log with truth (3 tracks), as Parquet and CSV."""
    d = tmp_path_factory.mktemp("sim")
    res = run("simulate", "--scenario", "gps", "--tracks", 3, "--duration", 120, "--seed", 5,
              "--out", d / "sim.parquet", "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["tracks"] == 3
    pd.read_parquet(d / "sim.parquet").to_csv(d / "sim.csv", index=False)
    return d


@pytest.mark.parametrize("source", ["gpx", "csv", "parquet"])
def test_each_input_format_tracks(tmp_path, sim, source):
    src = {"gpx": GPX, "csv": sim / "sim.csv", "parquet": sim / "sim.parquet"}[source]
    out = tmp_path / "tracks.parquet"
    res = run("track", src, "--out", out, "--json")
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    df = pd.read_parquet(out)
    assert summary["points_written"] == len(df) and summary["read"]["rows_skipped"] == 0
    assert df["track_id"].nunique() == (1 if source == "gpx" else 3)
    assert set(df["flag"]) <= {"init", "update", "manoeuvre", "outlier", "reset"}
    assert (df.groupby("track_id", sort=False)["flag"].first() == "init").all()
    assert summary["noise"]["sigma_source"] and summary["tracks"] == df["track_id"].nunique()
    assert not list(tmp_path.glob(".*"))  # no temporary files or parts left


def test_results_equal_the_library_api(tmp_path):
    """The CLI writes what the Python API returns, to the last bit (CSV keeps 17 digits), and what the
    per-track reference computes to rounding."""
    out = tmp_path / "t.csv"
    res = run("track", GPX, "--out", out, "--smooth", "--quiet")
    assert res.exit_code == 0, res.output
    api = track(GPX, smooth=True)
    got = pd.read_csv(out)
    for col in ("lat", "lon", "east_m", "var_east_m2", "nis", "vel_north_mps"):
        np.testing.assert_array_equal(got[col].to_numpy(), api[col].to_numpy())
    assert got["flag"].tolist() == api["flag"].tolist()
    est = api.attrs["tracks"].iloc[0]
    (tid, rows), = iter_tracks(GPX)
    ref = track_fixes(tid, rows, TrackOptions(smooth=True), fix_var=np.full(len(rows), est["sigma_m"] ** 2),
                      q=est["q"])
    np.testing.assert_allclose(got["lat"], ref["lat"], rtol=0, atol=1e-12)
    # at the 1 mm noise floor P = Pp - Pp^2/S cancels ~7 digits: compare on the scale of Pp (~10 m^2)
    np.testing.assert_allclose(got["var_east_m2"], ref["var_east_m2"], rtol=1e-10, atol=1e-10)


def test_geojson_output_is_valid_and_round_trips(tmp_path):
    geojson = pytest.importorskip("geojson")
    out = tmp_path / "t.geojson"
    res = run("track", GPX, "--out", out, "--smooth", "--sigma", 5.0, "--q", 2.0, "--quiet")
    assert res.exit_code == 0, res.output
    fc = geojson.loads(out.read_text())
    assert fc.is_valid
    (tid, rows), = iter_tracks(GPX)
    ref = track_fixes(tid, rows, TrackOptions(smooth=True, sigma_m=5.0, q=2.0))
    (line,) = json.loads(out.read_text())["features"]  # one per track, coordinates to 1e-7 degrees
    # (geojson.loads would round them to its default 6 decimals)
    assert line["geometry"]["type"] == "LineString"
    coords = np.array(line["geometry"]["coordinates"])
    np.testing.assert_allclose(coords[:, 1], ref["lat"], rtol=0, atol=5e-8)
    np.testing.assert_allclose(coords[:, 0], ref["lon"], rtol=0, atol=5e-8)
    assert line["properties"]["time"][0] == "2020-12-18T06:15:50Z"


def _bad_csv(tmp_path):
    (tid, rows), = iter_tracks(GPX)
    df = rows[["track_id", "time", "lat", "lon"]].copy()
    df["time"] = df["time"].dt.strftime("%Y-%m-%dT%H:%M:%SZ").astype(object)
    df.loc[41, "time"] = "2020-13-45T99:00:00Z"
    path = tmp_path / "bad.csv"
    df.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("suffix", [".parquet", ".geojson"])
def test_error_names_file_row_column_and_leaves_nothing(tmp_path, suffix):
    path = _bad_csv(tmp_path)
    out = tmp_path / f"out{suffix}"
    res = run("track", path, "--out", out, "--report", tmp_path / "r.html")
    assert res.exit_code == 2
    assert "bad.csv" in res.stderr and "row 42" in res.stderr and "'time'" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]


def test_skip_counts_and_reports_bad_rows(tmp_path):
    path = _bad_csv(tmp_path)
    out = tmp_path / "out.parquet"
    res = run("track", path, "--out", out, "--on-error", "skip", "--json")
    assert res.exit_code == 0, res.output
    read = json.loads(res.stdout)["read"]
    assert read["rows_read"] == 104 and read["rows_skipped"] == 1
    assert read["skipped_by_reason"] == {"time: bad time stamp": 1}
    assert len(pd.read_parquet(out)) == 103
    res = run("track", path, "--out", out, "--on-error", "skip")
    assert f"skipped: 1 of 104 rows of {path}:" in res.stderr and "1 × time: bad time stamp" in res.stderr
    assert "skipped: skipped" not in res.stderr


def test_resume_after_interruption(tmp_path, sim, monkeypatch):
    """An interrupted run keeps its finished chunks; --resume computes only the rest, and the output
    equals an uninterrupted run's."""
    out = tmp_path / "t.parquet"
    calls = []
    real = pipeline.TrackTask.__call__

    def interrupted(self, chunk):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(chunk.index)
        return real(self, chunk)

    monkeypatch.setattr(pipeline.TrackTask, "__call__", interrupted)
    with pytest.raises(KeyboardInterrupt):
        track_file(sim / "sim.parquet", out, chunk_rows=50)
    assert not out.exists() and len(PartStore(out).parts("points")) == 2
    calls.clear()
    monkeypatch.setattr(pipeline.TrackTask, "__call__", lambda self, c: calls.append(c.index) or real(self, c))
    res = run("track", sim / "sim.parquet", "--out", out, "--resume", "--chunk-rows", 50, "--json")
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["tracks"] == 3 and summary["chunks_resumed"] == 2 and calls == [2]
    monkeypatch.undo()
    fresh = tmp_path / "fresh.parquet"
    track_file(sim / "sim.parquet", fresh, chunk_rows=50)
    pd.testing.assert_frame_equal(pd.read_parquet(out), pd.read_parquet(fresh))
    assert not (tmp_path / ".t.parquet.parts").exists()


def test_resume_with_other_options_is_refused(tmp_path, sim, monkeypatch):
    out = tmp_path / "t.parquet"
    real = pipeline.TrackTask.__call__

    def interrupted(self, chunk):
        if chunk.index == 1:
            raise KeyboardInterrupt
        return real(self, chunk)

    monkeypatch.setattr(pipeline.TrackTask, "__call__", interrupted)
    with pytest.raises(KeyboardInterrupt):
        track_file(sim / "sim.parquet", out, chunk_rows=50)
    monkeypatch.undo()
    with pytest.raises(ParameterError, match="different"):
        track_file(sim / "sim.parquet", out, chunk_rows=50, resume=True, options=TrackOptions(smooth=True))
    assert not out.exists()


def test_cellular_pipeline_on_the_real_trace(tmp_path):
    log, cells = tmp_path / "cell.csv", tmp_path / "cells.csv"
    res = run("simulate", "--scenario", "urban-3bts", "--along", GPX, "--out", log, "--cells-out", cells,
              "--seed", 1, "--quiet")
    assert res.exit_code == 0, res.output
    out = tmp_path / "ct.parquet"
    res = run("track", log, "--cells", cells, "--method", "fekf", "--out", out, "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["cells"]["cells_used"] == 3
    res = run("evaluate", out, "--truth", log, "--json")
    overall = json.loads(res.stdout)["overall"]
    assert overall["matched_points"] == 104  # every real fix time is a scan
    assert overall["rmse_m"] < 400.0
    # a cell the table does not know (crowd-sourced tables are incomplete): its measurements are left out and
    # counted, with a note naming it and its first row -- not an error that stops the log
    table = pd.read_csv(cells)
    table.iloc[1:].to_csv(cells, index=False)
    res = run("track", log, "--cells", cells, "--out", tmp_path / "x.parquet", "--json")
    assert res.exit_code == 0, res.output
    read = json.loads(res.stdout)["read"]
    assert read["left_out"] == {"cell not in the cell table": 104} and read["skipped_by_reason"] == {}
    assert any("104 measurement(s) of 1 cell(s) not in the cell table" in n for n in read["notes"]), read["notes"]


def test_evaluate_against_truth(tmp_path, sim):
    out = tmp_path / "t.parquet"
    assert run("track", sim / "sim.parquet", "--out", out, "--quiet").exit_code == 0
    res = run("evaluate", out, "--truth", sim / "sim.parquet", "--json")
    assert res.exit_code == 0, res.output
    s = json.loads(res.stdout)
    o = s["overall"]
    assert o["matched_points"] == o["points"] and set(s["tracks"]) == {"sim0001", "sim0002", "sim0003"}
    # 5 m fixes, filtered; this seed has 4 outliers (one at track 1's third fix), all rejected by the gate
    assert o["cdf67_m"] < 7.0 and o["cdf95_m"] < 15.0 and o["rmse_m"] < 8.0
    assert s["tracks"]["sim0002"]["rmse_m"] < 6.0 and 1.0 < s["tracks"]["sim0002"]["mean_nees"] < 3.0
    assert o["nees_in_95"] > 0.85 and 1.0 < o["mean_nis"] < 4.0
    assert o["cdf50_m"] <= o["cdf67_m"] <= o["cdf95_m"]
    res = run("evaluate", out, "--truth", tmp_path / "missing.csv")
    assert res.exit_code == 2 and "file not found" in res.stderr


def test_evaluate_in_local_xy_metres(tmp_path, sim):
    """The same log given as x/y metres (with x/y truth) evaluates like the lat/lon log."""
    from mptrack.io import LocalFrame

    df = pd.read_parquet(sim / "sim.parquet")
    frame = LocalFrame(float(df["lat"].iloc[0]), float(df["lon"].iloc[0]))
    x, y = frame.to_enu(df["lat"].to_numpy(), df["lon"].to_numpy())
    tx, ty = frame.to_enu(df["true_lat"].to_numpy(), df["true_lon"].to_numpy())
    xy = df.drop(columns=["lat", "lon", "true_lat", "true_lon"]).assign(x=x, y=y, true_x=tx, true_y=ty)
    xy.to_parquet(tmp_path / "xy.parquet")
    geo_out, xy_out = tmp_path / "geo.parquet", tmp_path / "xy_tracks.parquet"
    assert run("track", sim / "sim.parquet", "--out", geo_out, "--quiet").exit_code == 0
    assert run("track", tmp_path / "xy.parquet", "--out", xy_out, "--quiet").exit_code == 0
    geo = json.loads(run("evaluate", geo_out, "--truth", sim / "sim.parquet", "--json").stdout)["overall"]
    res = run("evaluate", xy_out, "--truth", tmp_path / "xy.parquet", "--json")
    assert res.exit_code == 0, res.output
    flat = json.loads(res.stdout)["overall"]
    assert flat["matched_points"] == flat["points"] == geo["points"]
    assert flat["rmse_m"] == pytest.approx(geo["rmse_m"], rel=1e-3)
    assert flat["mean_nees"] == pytest.approx(geo["mean_nees"], rel=1e-2)
    # truth and tracks in different kinds of coordinates is an error, not a silent NaN
    res = run("evaluate", geo_out, "--truth", tmp_path / "xy.parquet")
    assert res.exit_code == 2 and "x/y" in res.stderr


def test_help_names_every_format_read():
    """`evaluate --help` lists every output format of `track` (its TRACKS) and every input format (its
    --truth); `track --help` every input format, .tsv included."""
    from mptrack.io import FORMATS, OUTPUT_FORMATS
    from mptrack.io._formats import FORMAT_NAMES

    def text(command):
        res = runner.invoke(app, [command, "--help"], env={"COLUMNS": "300"})
        assert res.exit_code == 0
        return " ".join(res.stdout.replace("│", " ").split())

    evaluate = text("evaluate")
    assert all(suffix in evaluate for suffix in OUTPUT_FORMATS), evaluate
    track_help = text("track")
    for name in FORMAT_NAMES.values():
        assert name in evaluate and name in track_help, name
    assert ".tsv" in FORMATS and "CSV (any delimiter" in track_help


def test_unknown_names_exit_2(tmp_path):
    res = run("track", GPX, "--out", tmp_path / "o.parquet", "--model", "ctrv")
    assert res.exit_code == 2 and "model: unknown motion model 'ctrv'" in res.stderr
    res = run("simulate", "--scenario", "rural", "--out", tmp_path / "s.csv")
    assert res.exit_code == 2 and "scenario" in res.stderr
    assert list(tmp_path.iterdir()) == []


def test_real_subprocess(tmp_path):
    env = dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "mptrack.cli"]
    out = tmp_path / "t.parquet"
    ok = subprocess.run(cmd + ["track", str(GPX), "--out", str(out), "--report", str(tmp_path / "r.html")],
                        capture_output=True, text=True, env=env, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert "1 tracks (0 resumed), 104 points" in ok.stdout and out.exists() and (tmp_path / "r.html").exists()
    bad = subprocess.run(cmd + ["track", str(_bad_csv(tmp_path)), "--out", str(tmp_path / "b.parquet")],
                         capture_output=True, text=True, env=env, timeout=120)
    assert bad.returncode == 2 and "row 42" in bad.stderr and not (tmp_path / "b.parquet").exists()


def _long_log(path, n_tracks, per=40):
    rng = np.random.default_rng(0)
    rows = n_tracks * per
    pd.DataFrame({"track_id": np.repeat([f"t{i:05d}" for i in range(n_tracks)], per),
                  "time": np.tile(np.cumsum(rng.uniform(0.5, 2.0, per)), n_tracks),
                  "x": rng.normal(0, 5, rows) + np.tile(np.arange(per) * 10.0, n_tracks),
                  "y": rng.normal(0, 5, rows)}).to_csv(path, index=False)


def _peak_bytes(path, out):
    import tracemalloc

    tracemalloc.start()
    try:
        track_file(path, out, chunk_rows=500)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_file(tmp_path):
    """Streaming: 8x the rows (and tracks) must need far less than 8x the memory (chunks of 500
    rows; what grows is the list of finished track ids and the Parquet footer, ~0.5 KB a track)."""
    _long_log(tmp_path / "small.csv", 25)
    _long_log(tmp_path / "large.csv", 200)
    track_file(tmp_path / "small.csv", tmp_path / "warm.parquet")  # imports, numba compilation
    small = _peak_bytes(tmp_path / "small.csv", tmp_path / "s.parquet")
    large = _peak_bytes(tmp_path / "large.csv", tmp_path / "l.parquet")
    assert len(pd.read_parquet(tmp_path / "l.parquet")) == 8000
    assert large < 2.0 * small, (small, large)


@pytest.mark.slow
def test_a_million_rows_in_bounded_memory(tmp_path):
    """10^6 rows (25 000 tracks) in a subprocess: peak resident memory well under 1 GiB."""
    _long_log(tmp_path / "big.csv", 25_000)
    code = ("import sys; from mptrack.tracking import track_file; "
            "track_file(sys.argv[1], sys.argv[2]); "  # VmHWM: ru_maxrss would count the forking pytest
            "print(next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1])")
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "big.csv"), str(tmp_path / "o.parquet")],
                          capture_output=True, text=True, timeout=3600)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.split()[-1]) < 1024 * 1024  # KiB


def test_an_output_that_is_the_input_is_refused(tmp_path):
    src = tmp_path / "log.csv"
    _bad_csv(tmp_path).replace(src)
    before = src.read_bytes()
    for args in (["--out", src], ["--out", tmp_path / "o.parquet", "--track-summary", src],
                 ["--out", tmp_path / "o.parquet", "--report", src]):
        res = run("track", src, *args)
        assert res.exit_code == 2 and "overwrite the input" in res.stderr, res.output
    for args in (["simulate", "--along", src, "--out", src],
                 ["simulate", "--scenario", "urban-3bts", "--along", src, "--out", tmp_path / "s.csv",
                  "--cells-out", src],
                 ["evaluate", src, "--report", src], ["evaluate", tmp_path / "t.csv", "--truth", src, "--report", src]):
        res = run(*args)
        assert res.exit_code == 2 and "overwrite the input" in res.stderr, res.output
    with pytest.raises(ParameterError, match="out: .* overwrite the input"):
        track_file(src, src)
    assert src.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["log.csv"]


def test_an_empty_file_is_a_clear_error(tmp_path):
    (tmp_path / "empty.csv").write_text("")
    res = run("track", tmp_path / "empty.csv", "--out", tmp_path / "o.parquet")
    assert res.exit_code == 2 and "empty.csv" in res.stderr and "cannot be read as csv" in res.stderr.lower()


def test_quiet_prints_nothing_but_errors(tmp_path):
    """-q: a run that prints a summary, the noise, notes and advice prints nothing at all; an error still
    prints its one line (exit 2).  A static receiver's NMEA log (../shared/data/receivers)."""
    from _data import shared_data

    log = shared_data("receivers", "gpsd-sirfstarv-nmea.log")

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "mptrack", *map(str, args)], capture_output=True, text=True,
                              timeout=600)

    loud = cli("track", log, "--out", tmp_path / "a.parquet", "--report", tmp_path / "a.html")
    assert loud.returncode == 0 and "noise:" in loud.stdout and "note:" in loud.stderr, loud.stderr
    for args in (("track", log, "--out", tmp_path / "a.parquet", "--report", tmp_path / "a.html", "-q"),
                 ("evaluate", tmp_path / "a.parquet", "--report", tmp_path / "e.html", "-q"),
                 ("simulate", "--tracks", 1, "--duration", 20, "--out", tmp_path / "s.csv", "-q")):
        quiet = cli(*args)
        assert (quiet.returncode, quiet.stdout, quiet.stderr) == (0, "", ""), args
    bad = cli("track", log, "--out", tmp_path / "a.parquet", "--sigma", "-1", "-q")
    assert bad.returncode == 2 and bad.stdout == "" and bad.stderr.startswith("error: --sigma")
    # --json asked for: the JSON, nothing else
    js = cli("track", log, "--out", tmp_path / "a.parquet", "--json", "-q")
    assert js.returncode == 0 and json.loads(js.stdout)["tracks"] == 1 and js.stderr == ""
