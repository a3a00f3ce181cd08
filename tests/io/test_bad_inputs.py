"""``mptrack track`` on a corpus of realistic mistakes (tests/data/bad/, made by make_corpus.py from
the first 40 fixes of the real car trace): the exit status, the key words of the message, and which
rows survive, for each file.

Files that are read (exit 0) must give the estimates of the clean file, good.csv, row for row: the
mistake was recognised and undone, not merely survived.
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from mptrack.cli import app

BAD = Path(__file__).parents[1] / "data" / "bad"
runner = CliRunner()

#: file -> (extra options, exit status, words the stderr must hold, rows in the output or None)
CASES = {
    "good.csv": ((), 0, [], 40),
    "bom.csv": ((), 0, [], 40),
    "crlf.csv": ((), 0, [], 40),
    "semicolon-decimal-comma.csv": ((), 0, [], 40),
    "quoted-numbers.csv": ((), 0, [], 40),
    "tz-offset.csv": ((), 0, [], 40),
    "mixed-tz.csv": ((), 0, [], 40),
    "odd-column-names.csv": ((), 0, [], 40),
    "row-id-column.csv": ((), 0, ["column 'id' has a different value in every row", "--columns track_id=id"], 40),
    "shuffled.csv": ((), 0, ["37 rows were not in (track, time) order and were sorted"], 40),
    "two-tracks-interleaved.csv": ((), 0, ["38 rows were not in (track, time) order"], 40),
    "duplicate-rows.csv": ((), 0, ["3 exact repeats of the row before them were dropped"], 40),
    "degrees-e7.csv": ((), 0, ["read as degrees x 10^7", "--coord-unit"], 40),
    "lat-lon-swapped.csv": ((), 0, ["holds values up to 113.7 deg, beyond 90", "swapped back"], 40),
    "lat-lon-swapped-tz.csv": ((), 0, ["warning: the time stamps' UTC offset +01:00 puts the fixes between 30 deg W "
                                       "and 45 deg E, but the longitude column 'lon' reads 45.27 deg",
                                       "--columns lat=lon,lon=lat"], 40),
    "lat-lon-swapped-tz.csv --columns": (("--columns", "lat=lon,lon=lat"), 0, [], 40),
    "epoch-milliseconds.csv": ((), 0, ["time: epoch milliseconds", "--time-unit"], 40),
    "epoch-seconds.csv": ((), 0, ["time: epoch seconds", "from 2020-12-18 06:15:50 UTC", "--time-unit"], 40),
    "epoch-seconds.csv --time-unit": (("--time-unit", "s"), 0, ["time: epoch seconds"], 40),
    "iso-without-zone.csv": ((), 0, ["time stamps without a zone (e.g. '2020-12-18T06:15:50') were read as UTC"],
                             40),
    "three-day-gap.csv": ((), 0, [], 40),
    "dd-mm-yyyy.csv": ((), 2, ["row 1, column 'time'", "not ISO 8601", "--time-format", "'18/12/2020 06:15:50'"],
                       None),
    "dd-mm-yyyy.csv --time-format": (("--time-format", "%d/%m/%Y %H:%M:%S"), 0,
                                     ["the layout '%d/%m/%Y %H:%M:%S' has no zone; the time stamps were read as "
                                      "UTC"], 40),
    "degrees-e6.csv": ((), 2, ["column 'lat'", "fit deg-e7 or deg-e6", "--coord-unit"], None),
    "degrees-e6.csv --coord-unit": (("--coord-unit", "deg-e6"), 0, [], 40),
    "radians.csv": ((), 2, ["as radians would", "--coord-unit rad"], None),
    "radians.csv --coord-unit": (("--coord-unit", "rad"), 0, [], 40),
    "epoch-ambiguous.csv": ((), 2, ["fit no unit unambiguously", "--time-unit"], None),
    "empty.csv": ((), 2, ["empty.csv", "the file is empty (0 bytes)"], None),
    "header-only.csv": ((), 2, ["no rows to track", "header only"], None),
    "garbage.csv": ((), 2, ["garbage.csv", "not UTF-8"], None),
    "spreadsheet.xlsx": ((), 2, ["unknown input format '.xlsx'"], None),
    "no-time-column.csv": ((), 2, ["column 'time'", "missing column", "track_id, lat, lon, elevation_m"], None),
    "unknown-column-names.csv": ((), 2, ["column 'lat+lon'", "the file has: track_id, time, Breite, Laenge, "
                                         "elevation_m", "name them with --columns lat=COLUMN,lon=COLUMN"], None),
    "unknown-column-names.csv --columns": (("--columns", "lat=Breite,lon=Laenge"), 0, [], 40),
    "two-latitudes.csv": ((), 2, ["'LAT', 'Latitude' all look like lat", "--columns lat=NAME"], None),
    "two-latitudes.csv --columns": (("--columns", "lat=Latitude"), 0, [], 40),
    "missing-latitude.csv": ((), 2, ["row 13, column 'lat'", "empty value"], None),
    "missing-latitude.csv skip": (("--on-error", "skip"), 2, ["1 of 40 rows would be dropped, more than the 0 "
                                                              "allowed by --max-skip 1%", "row 13"], None),
    "missing-latitude.csv skip 5%": (("--on-error", "skip", "--max-skip", "5%"), 0,
                                     ["skipped: 1 of 40 rows of", "lat: empty value"], 39),
    "same-time-other-position.csv": ((), 2, ["row 11, column 'time'", "repeats the track's previous time stamp "
                                             "with other values"], None),
    "untimed-point.gpx": ((), 2, ["row 6, column 'time'", "point 6 has no time stamp"], None),
}


def track(name: str, options, out: Path, quiet: bool = True):
    """The run of ``name``: quiet (-q: errors only), or not (its notes on stderr)."""
    return runner.invoke(app, ["track", str(BAD / name.split(" ")[0]), "--out", str(out), *options]
                         + (["-q"] if quiet else []))


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    out = tmp_path_factory.mktemp("good") / "good.parquet"
    assert track("good.csv", (), out).exit_code == 0
    return pd.read_parquet(out)


@pytest.mark.parametrize("name", list(CASES))
def test_each_mistake_has_its_outcome(tmp_path, good, name):
    options, status, words, rows = CASES[name]
    out = tmp_path / "out.parquet"
    res = track(name, options, out, quiet=bool(status))  # a run that works says what it noticed (not with -q)
    text = " ".join(res.stderr.split())  # the console wraps long lines
    assert res.exit_code == status, res.output
    for word in words:
        assert word in text
    if status:
        assert not out.exists() and list(tmp_path.iterdir()) == []   # nothing half-written, no parts
        assert len(res.stderr.strip().splitlines()) <= 3              # a message, not a traceback
        return
    got = pd.read_parquet(out)
    assert len(got) == rows
    if rows == 40 and name not in ("three-day-gap.csv", "lat-lon-swapped-tz.csv"):  # (a warning only)
        # undone, not survived: the clean file's estimates, row for row (degrees x 10^6 keep six
        # decimals; the swapped trace lies 100 degrees east, the same in metres)
        atol = 1e-6 if name.startswith("degrees-e6") else 2e-7
        east = 100.0 if name == "lat-lon-swapped.csv" else 0.0
        np.testing.assert_allclose(got["lat"], good["lat"], rtol=0, atol=atol)
        np.testing.assert_allclose(got["lon"] - east, good["lon"], rtol=0, atol=atol)
        np.testing.assert_allclose(got["t"], good["t"], rtol=0, atol=1e-6)
        pd.testing.assert_series_equal(got["time"], good["time"])  # UTC times, whatever the input's unit


def test_a_three_day_gap_is_flagged_and_the_track_goes_on(tmp_path, good):
    out = tmp_path / "gap.parquet"
    assert track("three-day-gap.csv", (), out).exit_code == 0
    got = pd.read_parquet(out)
    assert got["gap"].tolist() == [False] * 20 + [True] + [False] * 19
    assert got["t"].iloc[20] - got["t"].iloc[19] > 3 * 86400
    np.testing.assert_allclose(got["lat"].iloc[:20], good["lat"].iloc[:20], rtol=0, atol=1e-9)


def test_extra_columns_pass_through_to_the_output(good):
    """elevation_m of the input is a column of the output, row for row."""
    src = pd.read_csv(BAD / "good.csv")
    np.testing.assert_array_equal(good["elevation_m"], src["elevation_m"])


@pytest.mark.parametrize("name", ["accuracy_m", "HDOP"])
def test_accuracy_and_hdop_pass_through_to_the_output(tmp_path, name):
    """The input's accuracy column (or the HDOP it was made from, 5 m x HDOP) is in the output like
    any other column of the input, row for row."""
    values = np.round(np.linspace(0.8, 8.0, 40), 3)
    path = tmp_path / "in.csv"
    pd.read_csv(BAD / "good.csv").assign(**{name: values}).to_csv(path, index=False)
    out = tmp_path / "out.parquet"
    assert runner.invoke(app, ["track", str(path), "--out", str(out), "-q"]).exit_code == 0
    got = pd.read_parquet(out)
    np.testing.assert_array_equal(got[name], values)
    np.testing.assert_allclose(got["accuracy_m"], values * (5.0 if name == "HDOP" else 1.0), rtol=1e-12)


def test_the_corpus_is_complete():
    files = {p.name for p in BAD.iterdir() if p.name != "make_corpus.py"}
    assert files == {name.split(" ")[0] for name in CASES}


@pytest.mark.parametrize("name, words", [
    ("empty.csv", ["empty.csv: cannot be read as csv: the file is empty (0 bytes)"]),
    ("garbage.csv", ["garbage.csv: cannot be read as csv"]),
    ("good.csv", ["not a table written by mptrack track", "mptrack track LOG --out TRACKS"]),
])
def test_evaluate_names_a_file_it_cannot_use(name, words):
    res = runner.invoke(app, ["evaluate", str(BAD / name), "-q"])
    text = " ".join(res.stderr.split())
    assert res.exit_code == 2 and len(res.stderr.strip().splitlines()) <= 3, res.output
    for word in words:
        assert word in text


def test_evaluate_takes_a_gpx_trace_as_truth(tmp_path):
    """One reading layer: the truth may be any input format; one track matches one track whatever
    their names."""
    out = tmp_path / "t.parquet"
    assert track("good.csv", (), out).exit_code == 0
    gpx = BAD.parent / "around-visnjan-with-car.gpx"
    res = runner.invoke(app, ["evaluate", str(out), "--truth", str(gpx), "--json"])
    assert res.exit_code == 0, res.output
    import json

    overall = json.loads(res.stdout)["overall"]
    assert overall["matched_points"] == 40 and overall["rmse_m"] < 1.0
    res = runner.invoke(app, ["evaluate", str(out), "--truth", str(BAD / "three-day-gap.csv"), "--json"])
    assert json.loads(res.stdout)["overall"]["matched_points"] == 20


def test_epoch_seconds_become_gpx_times(tmp_path):
    """Epoch seconds are UTC times like epoch ms/us/ns: the GPX output has a <time> per point."""
    out = tmp_path / "es.gpx"
    assert track("epoch-seconds.csv", (), out).exit_code == 0
    text = out.read_text()
    assert text.count("<time>") == 40 and "<time>2020-12-18T06:15:50" in text


@pytest.mark.parametrize("name, options, without", [
    ("dd-mm-yyyy.csv", ("--time-format", "%d/%m/%Y %H:%M:%S"), "--time-format"),
    ("degrees-e6.csv", ("--coord-unit", "deg-e6"), "--coord-unit"),
    ("epoch-milliseconds.csv", ("--time-unit", "ms"), None),
    ("lat-lon-swapped-tz.csv", ("--columns", "lat=lon,lon=lat"), "--columns lat=lon,lon=lat"),
])
def test_along_and_truth_take_the_reading_options_of_track(tmp_path, good, name, options, without):
    """One reading layer: `simulate --along` and `evaluate --truth` read a file as `track` does, with
    the same --columns/--time-unit/--time-format/--coord-unit (an error or a warning naming the
    option without them)."""
    import json

    out = tmp_path / "t.parquet"
    assert track("good.csv", (), out).exit_code == 0
    res = runner.invoke(app, ["evaluate", str(out), "--truth", str(BAD / name), "--json", *options])
    assert res.exit_code == 0, res.output
    overall = json.loads(res.stdout)["overall"]
    assert overall["matched_points"] == 40 and overall["rmse_m"] < 1.0
    sim = tmp_path / "sim.parquet"
    res = runner.invoke(app, ["simulate", "--along", str(BAD / name), "--out", str(sim), "-q", *options])
    assert res.exit_code == 0, res.output
    truth = pd.read_parquet(sim)
    np.testing.assert_allclose(truth["true_lat"], good["meas_lat"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(truth["true_lon"], good["meas_lon"], rtol=0, atol=1e-6)
    if without is None:
        return
    for args in (["evaluate", str(out), "--truth", str(BAD / name)],
                 ["simulate", "--along", str(BAD / name), "--out", str(tmp_path / "s2.parquet")]):
        res = runner.invoke(app, args)  # not -q: a warning is printed only then
        assert without in " ".join(res.stderr.split()), res.output
        assert res.exit_code == (0 if name == "lat-lon-swapped-tz.csv" else 2)  # a swap is a warning only


def test_reading_options_without_their_file_are_refused():
    for args, option in ((["simulate", "--tracks", "1", "--out", "x.parquet"], "--along"),
                         (["evaluate", "x.parquet"], "--truth")):
        res = runner.invoke(app, args + ["--coord-unit", "rad"])
        assert res.exit_code == 2 and res.stderr.strip() == f"error: --coord-unit applies to the file read with {option}"
