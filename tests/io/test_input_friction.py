"""What a new user's files look like and how mptrack reads them without flags: a GeoLife CSV whose
X/Y are longitude/latitude in degrees (../shared/data/receivers), track ids under the names real
exports use, several files (a folder, a list, a glob) as one input with each file's tracks apart,
and an explicit --columns that is never overridden.  Local metres stay metres."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from mptrack.cli import app
from mptrack.errors import DataError
from mptrack.io import ReadOptions, ReadReport, read_table, resolve_input

from _data import REAL_TRACES, shared_data

runner = CliRunner()


def track(*args) -> tuple[int, dict | str]:
    res = runner.invoke(app, ["track", *map(str, args), "--json"])
    return res.exit_code, (json.loads(res.stdout) if res.exit_code == 0 else res.stderr)


@pytest.fixture(scope="module")
def geolife():
    return shared_data("receivers", "demodata_geolife.csv")


def test_geolife_csv_reads_as_five_trajectories_in_degrees(geolife, tmp_path):
    """X;Y in degrees, time column t, five trajectories in trajectory_id: read today as one track in
    local metres (lat NaN, q = 2e-10)."""
    code, summary = track(geolife, "--out", tmp_path / "g.parquet")
    assert code == 0, summary
    notes = " ".join(summary["read"]["notes"])
    assert "columns 'X'/'Y'" in notes and "read as lon/lat (--columns x=X,y=Y to read them as metres)" in notes
    points = pd.read_parquet(tmp_path / "g.parquet")
    assert sorted(points["track_id"].unique()) == ["1", "2", "3", "4", "5"]
    assert points["lat"].between(39.8, 40.1).all() and points["lon"].between(116.2, 116.7).all()
    assert points["origin_lat"].notna().all()
    raw = pd.read_csv(geolife, sep=";")
    assert len(points) == len(raw)
    np.testing.assert_allclose(points["meas_lat"], raw.sort_values(["trajectory_id", "t"], kind="stable")["Y"],
                               atol=1e-7)
    # a walk/drive in Beijing: the motion noise of metres, not of 1e-10 "metres" of degrees
    assert min(r["q"] for r in summary["track_noise"]) > 1e-3


def test_degree_ranges_under_every_xy_name(geolife, tmp_path):
    raw = pd.read_csv(geolife, sep=";").rename(columns={"t": "time"})
    for xn, yn in (("x", "y"), ("easting", "northing"), ("East", "North")):
        path = tmp_path / f"{xn}.csv"
        raw.rename(columns={"X": xn, "Y": yn}).to_csv(path, index=False)
        report = ReadReport()
        df = read_table(path, report=report)
        assert {"lat", "lon"} <= set(df.columns) and "x" not in df.columns, xn
        assert f"columns {xn!r}/{yn!r}" in " ".join(report.notes)
        np.testing.assert_allclose(df["lat"], raw["Y"])


def test_an_explicit_columns_is_never_overridden(geolife, tmp_path):
    # as metres, when the user says so (no degree detection)
    code, summary = track(geolife, "--columns", "x=X,y=Y", "--out", tmp_path / "m.parquet")
    assert code == 0 and not any("lon/lat" in n for n in summary["read"]["notes"])
    assert pd.read_parquet(tmp_path / "m.parquet")["lat"].isna().all()
    # lat/lon named the other way round: an error naming the option as given, not a swap behind its back
    code, message = track(geolife, "--columns", "lat=X,lon=Y", "--out", tmp_path / "s.parquet")
    assert code == 2 and "--columns lat=X: that column holds values around 116.4, beyond 90" in message
    assert "--columns lat=Y,lon=X" in message and not (tmp_path / "s.parquet").exists()
    code, summary = track(geolife, "--columns", "lat=Y,lon=X", "--out", tmp_path / "d.parquet")
    assert code == 0 and not any("swapped" in n for n in summary["read"]["notes"])
    # a file with its columns swapped, named as they are: refused, not swapped back
    swapped = Path(__file__).parents[1] / "data" / "bad" / "lat-lon-swapped.csv"
    code, message = track(swapped, "--columns", "lat=lat,lon=lon", "--out", tmp_path / "x.parquet")
    assert code == 2 and "--columns lat=lat: that column holds values around" in message
    code, summary = track(swapped, "--out", tmp_path / "y.parquet")  # unnamed: swapped back, with a note
    assert code == 0 and any("swapped back" in n for n in summary["read"]["notes"])


def _xy_log(tmp_path, name, x, y, dt):
    path = tmp_path / name
    pd.DataFrame({"time": np.arange(len(x)) * dt, "x": x, "y": y}).to_csv(path, index=False)
    return path


def test_local_metres_stay_metres(tmp_path):
    rng = np.random.default_rng(3)
    n = 500
    # a 50 Hz trace in metres near its origin (every value within the degree ranges): 10 m/s
    fast = _xy_log(tmp_path, "fast.csv", 10 * np.arange(n) / 50, rng.normal(0, 0.05, n), 0.02)
    # a static logger in metres, centimetre noise, 60 m from its origin, 1 Hz
    static = _xy_log(tmp_path, "static.csv", 60 + rng.normal(0, 0.01, n), 20 + rng.normal(0, 0.01, n), 1.0)
    for path in (fast, static):
        report = ReadReport()
        df = read_table(path, report=report)
        assert {"x", "y"} <= set(df.columns) and "lat" not in df.columns, path.name
        assert not any("lon/lat" in n for n in report.notes)
    # a value beyond 180: metres without a look at the speeds
    assert "x" in read_table(_xy_log(tmp_path, "far.csv", 200 + np.arange(5.0), np.zeros(5), 1.0)).columns


def test_degrees_or_metres_that_cannot_be_told_apart_are_refused(tmp_path):
    """A receiver that never moved, at 116.39/39.90: degrees in Beijing, or metres beside an origin?"""
    path = _xy_log(tmp_path, "still.csv", np.full(20, 116.391305), np.full(20, 39.898573), 1.0)
    with pytest.raises(DataError, match=r"columns 'x'/'y' hold values around 116.391/39.8986: longitude/latitude "
                                        r"in degrees or local metres\? .* --columns lon=x,lat=y \(degrees\) or "
                                        r"--columns x=x,y=y \(metres\)"):
        read_table(path)
    assert "lat" in read_table(path, read=ReadOptions(columns="lon=x,lat=y")).columns
    assert "x" in read_table(path, read=ReadOptions(columns="x=x,y=y")).columns
    # near the origin or in whole numbers: metres, as ever
    assert "x" in read_table(_xy_log(tmp_path, "zero.csv", np.zeros(20), np.zeros(20), 1.0)).columns


@pytest.mark.parametrize("column", ["trajectory_id", "traj_id", "user_id", "vehicle_id", "imei", "mmsi",
                                    "Trajectory ID", "MMSI"])
def test_track_id_synonyms(tmp_path, column):
    df = pd.DataFrame({column: np.repeat(["a", "b"], 5), "time": np.tile(np.arange(5.0), 2),
                       "lat": 45.0 + 1e-5 * np.arange(10), "lon": 13.0 + 1e-5 * np.arange(10)})
    df.to_csv(tmp_path / "ids.csv", index=False)
    assert sorted(read_table(tmp_path / "ids.csv")["track_id"].unique()) == ["a", "b"]


def test_a_trajectory_wins_over_its_user_and_a_row_number(tmp_path):
    df = pd.DataFrame({"id": np.arange(12), "user_id": ["u"] * 12, "trajectory_id": np.repeat(["a", "b", "c"], 4),
                       "time": np.tile(np.arange(4.0), 3), "lat": 45.0 + 1e-5 * np.arange(12), "lon": 13.0})
    df.to_csv(tmp_path / "ids.csv", index=False)
    report = ReadReport()
    out = read_table(tmp_path / "ids.csv", report=report)
    assert sorted(out["track_id"].unique()) == ["a", "b", "c"]
    assert "track id: column 'trajectory_id' (also found 'user_id'; --columns track_id=NAME to take another)" \
        in report.notes
    assert read_table(tmp_path / "ids.csv", read=ReadOptions(columns="track_id=user_id"))["track_id"].nunique() == 1
    df.drop(columns="trajectory_id").assign(vehicle_id="v", imei="i").to_csv(tmp_path / "two.csv", index=False)
    with pytest.raises(DataError, match="columns 'vehicle_id', 'imei' all look like track_id"):
        read_table(tmp_path / "two.csv")


@pytest.fixture
def rides(tmp_path):
    """A folder of GPX files, an NMEA log and a file of no input format."""
    d = tmp_path / "rides"
    d.mkdir()
    for kind in ("car", "bike"):
        shutil.copy(REAL_TRACES[kind], d)
    shutil.copy(shared_data("receivers", "gpsd-ublox-neo-m9n-nmea.log"), d)
    (d / "README.md").write_text("rides of the week\n")
    return d


def test_a_folder_of_gpx_files_is_one_input_with_each_files_tracks_apart(rides, tmp_path):
    """A folder of GPX files failed with pyarrow's 'Parquet magic bytes not found'."""
    code, summary = track(rides)
    assert code == 0, summary
    out = rides.parent / "rides.tracks.parquet"  # beside the folder, not inside it
    points = pd.read_parquet(out)
    assert sorted(points["track_id"].unique()) == [
        "around-visnjan-with-car.gpx/2020-12-18 07:24:29", "berkelland-bike-ride.gpx/Berkelland Fietsen",
        "gpsd-ublox-neo-m9n-nmea.log/gpsd-ublox-neo-m9n-nmea"]
    assert summary["read"]["left_out"] == {"file of no input format": 1}
    assert any("README.md: not an input format" in n for n in summary["read"]["notes"])
    assert any(n.startswith("gpsd-ublox-neo-m9n-nmea.log: accuracy: ") for n in summary["read"]["notes"])
    # each file alone gives the same estimates (its tracks are its own)
    code, alone = track(REAL_TRACES["car"], "--out", tmp_path / "car.parquet")
    car = pd.read_parquet(tmp_path / "car.parquet")
    mine = points[points["track_id"].str.startswith("around-visnjan")].reset_index(drop=True)
    np.testing.assert_array_equal(mine["east_m"], car["east_m"])
    # the output inside the folder is refused (a later run on the folder would read it)
    code, message = track(rides, "--out", rides / "t.parquet")
    assert code == 2 and "inside the input directory" in message


def test_several_files_and_a_glob(rides, tmp_path):
    """Two input files gave 'unexpected extra argument'."""
    files = sorted(rides.glob("*.gpx"))
    code, listed = track(*files, "--out", tmp_path / "two.parquet")
    assert code == 0, listed
    code, globbed = track(rides / "*.gpx", "--out", tmp_path / "glob.parquet")
    assert code == 0, globbed
    a, b = pd.read_parquet(tmp_path / "two.parquet"), pd.read_parquet(tmp_path / "glob.parquet")
    pd.testing.assert_frame_equal(a, b)
    assert a["track_id"].nunique() == 2 and listed["input"] == f"2 files in {rides}"
    # two files that call their track by one name stay two tracks
    shutil.copy(files[0], tmp_path / "copy.gpx")
    code, twice = track(files[0], tmp_path / "copy.gpx", "--out", tmp_path / "twice.parquet")
    assert code == 0 and twice["tracks"] == 2
    # several files default to an output beside their common folder
    code, summary = track(*files)
    assert code == 0 and summary["output"] == str(rides.parent / "rides.tracks.parquet")
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "README.md").write_text("x")
    for bad, words in (([rides / "nothing-*.gpx"], "no file matches this pattern"),
                       ([notes], "no input files in the directory: README.md of no input format"),
                       ([files[0], files[0]], "a file is given twice"),
                       ([files[0], rides], "is a directory")):
        code, message = track(*bad, "--out", tmp_path / "x.parquet")
        assert code == 2 and words in message, message


def test_resolve_input():
    assert resolve_input(REAL_TRACES["car"]) == REAL_TRACES["car"]
    assert resolve_input([REAL_TRACES["car"]]) == REAL_TRACES["car"]
    both = resolve_input([REAL_TRACES["bike"], REAL_TRACES["car"]])
    assert isinstance(both, list) and both == [REAL_TRACES["bike"], REAL_TRACES["car"]]
    assert resolve_input(str(REAL_TRACES["car"].parent / "*-car.gpx")) == REAL_TRACES["car"]


def test_an_earlier_output_in_the_folder_is_left_out(rides, tmp_path):
    """A folder of logs that also holds an earlier run's output: the output is not tracked again."""
    code, _ = track(rides / "around-visnjan-with-car.gpx", "--out", rides / "car.tracks.parquet")
    assert code == 0
    code, summary = track(rides, "--out", tmp_path / "all.parquet")
    assert code == 0, summary
    assert summary["tracks"] == 3 and summary["read"]["left_out"]["output of mptrack track"] == 1
    assert not any(t.startswith("car.tracks.parquet") for t in pd.read_parquet(tmp_path / "all.parquet")["track_id"])
