"""Input schemas, chunked readers, file/row/column errors, skipping and atomic writers
(the ENU frames are tested in test_io_geodesy.py)."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mptrack.errors import DataError, ParameterError
from mptrack.io import (
    ReadOptions,
    CELLS,
    FIXES,
    MEASUREMENTS,
    ReadReport,
    input_columns,
    iter_tracks,
    read_cells,
    read_table,
    write_table,
)

DATA = Path(__file__).parents[1] / "data"
GPX = DATA / "around-visnjan-with-car.gpx"


def fixes_frame(n_tracks=3, n=6):
    rows = []
    for k in range(n_tracks):
        for i in range(n):
            rows.append({"track_id": f"t{k}", "time": f"2024-01-01T00:{k:02d}:{2 * i:02d}Z",
                         "lat": 45.0 + 1e-4 * i, "lon": 13.0 + 1e-4 * k, "accuracy_m": 4.0})
    return pd.DataFrame(rows)


@pytest.fixture
def fixes_csv(tmp_path):
    path = tmp_path / "fixes.csv"
    fixes_frame().to_csv(path, index=False)
    return path


def test_gpx_real_trace_reads_with_irregular_times():
    tracks = list(iter_tracks(GPX))
    assert len(tracks) == 1
    tid, df = tracks[0]
    assert tid == "2020-12-18 07:24:29" and len(df) == 104
    dt = np.diff(df["t"].to_numpy())
    assert dt.min() == 1.0 and dt.max() == 49.0  # a Garmin eTrex logging at irregular intervals
    assert df["lat"].iloc[0] == pytest.approx(45.2735188510)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_csv_and_parquet_give_the_same_tracks(tmp_path, fmt):
    df = fixes_frame()
    path = tmp_path / f"f.{fmt}"
    df.to_csv(path, index=False) if fmt == "csv" else df.to_parquet(path, index=False)
    got = dict(iter_tracks(path, chunk_rows=4))  # chunks cut through tracks
    assert list(got) == ["t0", "t1", "t2"]
    for k, (tid, g) in enumerate(got.items()):
        assert g["row"].tolist() == list(range(6 * k + 1, 6 * k + 7))
        assert np.allclose(np.diff(g["t"]), 2.0)


def test_numeric_seconds_and_xy_columns(tmp_path):
    path = tmp_path / "xy.csv"
    pd.DataFrame({"time": [0.0, 1.5, 4.0], "x": [0, 1, 2], "y": [0, 0, 1]}).to_csv(path, index=False)
    (tid, g), = iter_tracks(path)
    assert tid == "1" and g["t"].tolist() == [0.0, 1.5, 4.0]


def _edit(tmp_path, name, fn, frame=None):
    df = fixes_frame() if frame is None else frame
    df = fn(df) if fn else df
    path = tmp_path / name
    df.to_csv(path, index=False)
    return path


ERRORS = [
    ("missing column", lambda d: d.drop(columns="time"), None, "time", "missing column"),
    ("no position", lambda d: d.drop(columns=["lat"]), None, "lat+lon", "missing columns"),
    ("bad time", lambda d: d.assign(time=d["time"].where(d.index != 4, "yesterday")), 5, "time", "bad time stamp"),
    ("NaN latitude", lambda d: d.assign(lat=d["lat"].where(d.index != 7)), 8, "lat", "empty value"),
    ("latitude range", lambda d: d.assign(lat=d["lat"].where(d.index != 2, 91.0)), 3, "lat", "outside"),
    ("not a number", lambda d: d.assign(lon=d["lon"].astype(object).where(d.index != 9, "east")), 10, "lon",
     "not a number"),
    ("unsorted", lambda d: d.iloc[[0, 1, 3, 2, 4, 5] + list(range(6, 18))], 4, "time", "is before the track"),
    ("not contiguous", lambda d: d.iloc[list(range(0, 6)) + list(range(12, 18)) + list(range(6, 12))]
     .assign(track_id=lambda x: ["t0"] * 6 + ["t2"] * 6 + ["t0"] * 6), 13, "track_id", "appears again"),
]


@pytest.mark.parametrize("case", ERRORS, ids=[c[0] for c in ERRORS])
def test_errors_name_file_row_and_column(tmp_path, case):
    _, edit, row, column, text = case
    path = _edit(tmp_path, "bad.csv", edit)
    with pytest.raises(DataError) as info:
        for _ in iter_tracks(path, chunk_rows=5):
            pass
    err = info.value
    assert err.file == path and err.row == row and err.column == column
    assert str(path) in str(err) and text in str(err) and isinstance(err, ValueError)
    if row is not None:
        assert f"row {row}" in str(err)


def test_skip_counts_every_bad_row_by_reason(tmp_path):
    def edit(d):
        d = d.copy()
        d.loc[1, "time"] = "garbage"
        d.loc[3, "lat"] = np.nan
        d.loc[8, "lat"] = -95.0
        return d.iloc[[0, 1, 2, 3, 5, 4] + list(range(6, 18))]  # row 6 (index 4) goes back in time

    path = _edit(tmp_path, "bad.csv", edit)
    report = ReadReport()
    tracks = dict(iter_tracks(path, on_error="skip", report=report, chunk_rows=4, read=ReadOptions(max_skip="25%")))
    assert report.rows_read == 18 and report.rows_skipped == 4
    assert sum(len(g) for g in tracks.values()) == 14
    assert report.reasons == {"time: bad time stamp": 1, "lat: empty value (NaN)": 1,
                              "lat: outside -90.0 .. 90.0 degrees": 1, "time: time not increasing": 1}
    assert any("row 2" in e for e in report.examples)
    assert json.dumps(report.to_dict())


def test_unknown_on_error_policy_is_rejected(fixes_csv):
    with pytest.raises(ParameterError, match="on_error"):
        read_table(fixes_csv, on_error="ignore")


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(DataError, match="file not found"):
        read_table(tmp_path / "nope.csv")
    bad = tmp_path / "x.parquet"
    bad.write_text("not parquet")
    with pytest.raises(DataError, match="(?i)cannot be read as parquet"):
        read_table(bad)
    with pytest.raises(DataError, match="unknown input format"):
        read_table(tmp_path / "x.xlsx")
    gpx = tmp_path / "t.gpx"
    gpx.write_text("<gpx><trk><trkseg><trkpt lat='45' lon='13'></trkpt></trkseg></trk></gpx>")
    with pytest.raises(DataError) as info:
        read_table(gpx)
    assert info.value.row == 1 and info.value.column == "time"


def cell_table():
    return pd.DataFrame({"radio": ["GSM"] * 3, "mcc": [262] * 3, "net": [1] * 3, "area": [7] * 3,
                         "cell": [1, 2, 3], "unit": 0, "lon": [13.0, 13.01, 13.02], "lat": [45.0, 45.01, 45.0],
                         "range": 1000, "samples": 3, "changeable": 1, "created": 0, "updated": 0,
                         "averageSignal": 0, "arfcn": [700, None, 30]})


def test_cell_table_opencellid_layout_and_defaults(tmp_path):
    path = tmp_path / "cells.csv"
    cell_table().to_csv(path, index=False)
    cells = read_cells(path, wanted={"262-1-7-1", "262-1-7-3", "999-1-1-1"})
    assert list(cells.index) == ["262-1-7-1", "262-1-7-3"]
    assert cells["height_m"].tolist() == [30.0, 30.0] and cells["power_dbm"].tolist() == [43.0, 43.0]
    assert cells["arfcn"].tolist() == [700, 30]


def test_cell_table_errors(tmp_path):
    path = tmp_path / "cells.csv"
    cell_table().assign(cell=[1, 2, 1]).to_csv(path, index=False)
    with pytest.raises(DataError) as info:
        read_cells(path)
    assert info.value.row == 3 and info.value.column == "cell" and "listed twice" in str(info.value)
    cell_table().drop(columns="mcc").to_csv(path, index=False)
    with pytest.raises(DataError, match="'mcc': missing column") as info:
        read_cells(path)
    assert "--columns" not in str(info.value)  # the cell table's layout is fixed
    cell_table().iloc[:0].to_csv(path, index=False)
    with pytest.raises(DataError) as info:
        read_cells(path)
    assert str(info.value) == f"{path}: the cell table is empty: it has a header only, no cells"


def test_missing_position_columns_list_the_files_columns(tmp_path):
    """The file's own column names (not the mapped ones) and the option that maps them."""
    path = tmp_path / "de.csv"
    fixes_frame().rename(columns={"lat": "Breite", "lon": "Laenge", "time": "Zeit"}).to_csv(path, index=False)
    with pytest.raises(DataError) as info:
        read_table(path, read=ReadOptions(columns={"time": "Zeit"}))
    assert str(info.value) == (f"{path}, column 'lat+lon': missing columns: need lat+lon or x+y (the file has: "
                               "track_id, Zeit, Breite, Laenge, accuracy_m); name them with --columns "
                               "lat=COLUMN,lon=COLUMN")
    got = read_table(path, read=ReadOptions(columns={"time": "Zeit", "lat": "Breite", "lon": "Laenge"}))
    assert got["lat"].tolist() == fixes_frame()["lat"].tolist()


def test_tsv_is_read_as_csv(tmp_path):
    path = tmp_path / "fixes.tsv"
    fixes_frame().to_csv(path, sep="\t", index=False)
    got = read_table(path)
    assert len(got) == 18 and got["lon"].tolist() == fixes_frame()["lon"].tolist()


def test_measurement_rows_need_one_measurement(tmp_path):
    path = tmp_path / "m.csv"
    pd.DataFrame({"track_id": "a", "time": [1.0, 1.0, 2.0], "cell_id": ["262-1-7-1"] * 3,
                  "rss_dbm": [-70.0, np.nan, -71.0], "ta": [np.nan, np.nan, 3]}).to_csv(path, index=False)
    with pytest.raises(DataError) as info:
        read_table(path, MEASUREMENTS)
    assert info.value.row == 2 and info.value.column == "rss_dbm/ta"
    # equal times within a track are one scan: allowed for measurement logs
    (tid, g), = iter_tracks(path, MEASUREMENTS, on_error="skip", read=ReadOptions(max_skip="1"))
    assert len(g) == 2


def test_schemas_render_as_markdown():
    for schema in (FIXES, MEASUREMENTS, CELLS):
        md = schema.markdown()
        assert md.startswith("| column | required | unit |") and ("`time`" in md or "`mcc`" in md)


# ---- writers ---------------------------------------------------------------------------------------

def _table():
    return pd.DataFrame({"track_id": ["a", "a", "b"], "t": [0.0, 1.0, 0.0], "lat": [45.0, 45.001, 46.0],
                         "lon": [13.0, 13.001, 14.0], "nis": [np.nan, 1.5, 0.3],
                         "time": pd.to_datetime([0, 1, 0], unit="s", utc=True)})


@pytest.mark.parametrize("suffix", [".parquet", ".csv", ".geojson"])
def test_writers_roundtrip(tmp_path, suffix):
    path = write_table(_table(), tmp_path / f"out{suffix}")
    if suffix == ".parquet":
        back = pd.read_parquet(path)
        assert back["nis"].isna().tolist() == [True, False, False]
    elif suffix == ".csv":
        back = pd.read_csv(path)
        assert back["lat"].tolist() == [45.0, 45.001, 46.0]
    else:
        geojson = pytest.importorskip("geojson")
        fc = geojson.loads(path.read_text())
        assert fc.is_valid and fc["type"] == "FeatureCollection"
        line, point = fc["features"]  # one feature per track: a LineString, a Point for one fix
        assert line["geometry"]["type"] == "LineString" and point["geometry"]["type"] == "Point"
        assert line["geometry"]["coordinates"][1] == [13.001, 45.001]
        assert line["properties"]["nis"] == [None, 1.5] and point["properties"]["nis"] == 0.3
        assert line["properties"]["time"] == ["1970-01-01T00:00:00Z", "1970-01-01T00:00:01Z"]


def test_csv_writer_round_trips_times_floats_and_text(tmp_path):
    """Times come back as the same instants through the readers (ISO 8601 with Z, coarsest exact unit);
    floats bit for bit; text with commas and quotes, booleans and missing values survive pandas' reader."""
    rng = np.random.default_rng(1)
    ns = pd.to_datetime([0, 1_500_000_000, 2_000_000_001], unit="ns", utc=True)
    df = pd.DataFrame({"track_id": ["a,1", 'b"2', "3"], "time": pd.to_datetime([0, 1250, 2000], unit="ms", utc=True),
                       "lat": 45.0 + rng.random(3), "lon": [13.0, np.nan, 13.1], "flag": [True, False, True],
                       "naive": pd.to_datetime(["2024-01-01T00:00:01", None, "2024-01-01T00:00:02"]), "t_ns": ns})
    path = write_table(df, tmp_path / "o.csv")
    text = path.read_text().splitlines()
    assert text[0] == "track_id,time,lat,lon,flag,naive,t_ns"
    assert text[1].startswith('"a,1","1970-01-01T00:00:00.000Z",') and "2024-01-01T00:00:01Z" in text[1]
    assert text[3].endswith('"1970-01-01T00:00:02.000000001Z"')
    write_table(df.iloc[2:], tmp_path / "plain.csv")  # nothing to quote: plain fields, like pandas
    assert (tmp_path / "plain.csv").read_text().splitlines()[1] == (
        f"3,1970-01-01T00:00:02Z,{float(df['lat'].iloc[2])!r},13.1,true,2024-01-01T00:00:02Z,"
        "1970-01-01T00:00:02.000000001Z")
    back = pd.read_csv(path, dtype={"track_id": "string"})
    assert back["track_id"].tolist() == df["track_id"].tolist() and back["flag"].tolist() == [True, False, True]
    np.testing.assert_array_equal(back["lat"], df["lat"])
    assert back["lon"].isna().tolist() == [False, True, False]
    for col in ("time", "naive", "t_ns"):
        got = pd.to_datetime(back[col], utc=True, format="ISO8601")
        pd.testing.assert_series_equal(got, df[col].dt.tz_localize("UTC") if df[col].dt.tz is None else df[col],
                                       check_names=False, check_dtype=False)
    t = read_table(write_table(df.assign(lon=13.0), tmp_path / "fixes.csv"))["t"].to_numpy()
    np.testing.assert_array_equal(t, [0.0, 1.25, 2.0])


def test_write_is_atomic(tmp_path):
    def frames():
        yield _table()
        raise RuntimeError("interrupted")

    out = tmp_path / "out.csv"
    with pytest.raises(RuntimeError):
        write_table(frames(), out)
    assert list(tmp_path.iterdir()) == []


def test_user_guide_shows_the_current_schemas():
    guide = (Path(__file__).parents[2] / "docs" / "tracking.md").read_text()
    for schema in (FIXES, MEASUREMENTS, CELLS):
        assert schema.markdown() in guide


def test_time_zones_and_datetime_columns(tmp_path):
    times = pd.to_datetime(["2024-01-01T00:00:00", "2024-01-01T00:00:01.5", "2024-01-01T00:00:03"], format="ISO8601")
    df = pd.DataFrame({"track_id": "a", "time": times, "lat": [45.0, 45.0001, 45.0002], "lon": 13.0})
    df.to_parquet(tmp_path / "naive.parquet")  # naive datetimes are UTC
    df.assign(time=times.tz_localize("Europe/Zagreb")).to_parquet(tmp_path / "zoned.parquet")
    df.assign(time=["2024-01-01T01:00:00+01:00", "2024-01-01T00:00:01.5Z", "2024-01-01 00:00:03"]).to_csv(
        tmp_path / "mixed.csv", index=False)
    starts = {}
    for name in ("naive.parquet", "zoned.parquet", "mixed.csv"):
        (_, g), = iter_tracks(tmp_path / name)
        assert np.diff(g["t"]).tolist() == [1.5, 1.5]
        starts[name] = g["t"].iloc[0]
    assert starts["naive.parquet"] == starts["mixed.csv"] == starts["zoned.parquet"] + 3600.0


#: (place, lat, lon, IANA zone): the extremes of legal time against longitude (western China, Spain in
#: summer, Iceland, Argentina, the Pacific around the date line) and the usual places.
PLACES = [
    ("Madrid", 40.42, -3.70, "Europe/Madrid"), ("A Coruna", 43.36, -8.41, "Europe/Madrid"),
    ("Brest", 48.39, -4.49, "Europe/Paris"), ("Paris", 48.86, 2.35, "Europe/Paris"),
    ("London", 51.5, -0.12, "Europe/London"), ("Reykjavik", 64.15, -21.94, "Atlantic/Reykjavik"),
    ("Kashgar", 39.47, 75.99, "Asia/Shanghai"), ("Tashkurgan", 37.77, 75.23, "Asia/Shanghai"),
    ("Urumqi", 43.83, 87.62, "Asia/Urumqi"), ("Lhasa", 29.65, 91.1, "Asia/Shanghai"),
    ("Beijing", 39.9, 116.4, "Asia/Shanghai"), ("Harbin", 45.8, 126.5, "Asia/Shanghai"),
    ("Buenos Aires", -34.6, -58.4, "America/Argentina/Buenos_Aires"),
    ("Ushuaia", -54.8, -68.3, "America/Argentina/Ushuaia"), ("Anchorage", 61.2, -149.9, "America/Anchorage"),
    ("Nome", 64.5, -165.4, "America/Nome"), ("Adak", 51.9, -176.6, "America/Adak"),
    ("Honolulu", 21.3, -157.9, "Pacific/Honolulu"), ("Kiritimati", 1.87, -157.4, "Pacific/Kiritimati"),
    ("Apia", -13.8, -171.8, "Pacific/Apia"), ("Auckland", -36.85, 174.76, "Pacific/Auckland"),
    ("Chatham", -43.95, -176.55, "Pacific/Chatham"), ("Perth", -31.95, 115.86, "Australia/Perth"),
    ("Eucla", -31.7, 128.9, "Australia/Eucla"), ("Darwin", -12.46, 130.84, "Australia/Darwin"),
    ("Tokyo", 35.68, 139.7, "Asia/Tokyo"), ("Anadyr", 64.7, 177.5, "Asia/Anadyr"),
    ("Kaliningrad", 54.7, 20.5, "Europe/Kaliningrad"), ("Moscow", 55.75, 37.6, "Europe/Moscow"),
    ("Cairo", 30.04, 31.24, "Africa/Cairo"), ("Lagos", 6.5, 3.4, "Africa/Lagos"),
    ("Casablanca", 33.6, -7.6, "Africa/Casablanca"), ("Laayoune", 27.15, -13.2, "Africa/El_Aaiun"),
    ("Nairobi", -1.29, 36.82, "Africa/Nairobi"), ("Mumbai", 19.08, 72.88, "Asia/Kolkata"),
    ("Kathmandu", 27.7, 85.3, "Asia/Kathmandu"), ("Singapore", 1.35, 103.8, "Asia/Singapore"),
    ("New York", 40.7, -74.0, "America/New_York"), ("Los Angeles", 34.05, -118.24, "America/Los_Angeles"),
    ("Mexico City", 19.4, -99.1, "America/Mexico_City"), ("Lima", -12.05, -77.04, "America/Lima"),
    ("Easter Island", -27.1, -109.35, "Pacific/Easter"), ("Sao Paulo", -23.55, -46.63, "America/Sao_Paulo"),
    ("Nuuk", 64.18, -51.7, "America/Nuuk"), ("Azores", 37.74, -25.67, "Atlantic/Azores"),
    ("St Johns", 47.56, -52.71, "America/St_Johns"), ("Tehran", 35.7, 51.4, "Asia/Tehran"),
    ("Hovd", 48.0, 91.6, "Asia/Hovd"), ("Magadan", 59.56, 150.8, "Asia/Magadan"),
    ("Samara", 53.2, 50.1, "Europe/Samara"), ("Visnjan", 45.27, 13.71, "Europe/Zagreb"),
    ("Lubumbashi", -11.66, 27.48, "Africa/Lubumbashi"), ("Tongatapu", -21.1, -175.2, "Pacific/Tongatapu"),
    ("Marquesas", -9.0, -139.5, "Pacific/Marquesas"), ("Galapagos", -0.9, -89.6, "Pacific/Galapagos"),
]


def test_the_utc_offset_flags_swapped_columns_and_no_real_place():
    """The swap check from the time stamps' UTC offset: no warning for any of these places in winter
    or summer (their real offsets, from the IANA zone database), a warning for most of them with
    the columns swapped (a swap within the valid ranges; 27 of the 58 cases here: the documented
    limit), and no opinion without an offset (Z, +00:00)."""
    from datetime import datetime

    from mptrack.io._interpret import Interpretation, _zone_check

    zoneinfo = pytest.importorskip("zoneinfo")

    def warned(lat, lon, offset):  # offset in seconds
        sign, secs = "+-"[offset < 0], abs(int(offset))
        time = f"2023-01-15T12:00:00{sign}{secs // 3600:02d}:{secs % 3600 // 60:02d}"
        plan = Interpretation()
        _zone_check(pd.DataFrame({"time": [time] * 3, "lat": [lat] * 3, "lon": [lon] * 3}), plan)
        return bool(plan.notes)

    caught = cases = 0
    for name, lat, lon, zone in PLACES:
        for month in (1, 7):
            try:
                offset = datetime(2023, month, 15, 12, tzinfo=zoneinfo.ZoneInfo(zone)).utcoffset().total_seconds()
            except zoneinfo.ZoneInfoNotFoundError:
                pytest.skip("no time zone database")
            assert not warned(lat, lon, offset), (name, month)
            if abs(lon) <= 90 and offset:
                cases += 1
                caught += warned(lon, lat, offset)
    assert (caught, cases) == (27, 58)
    assert not warned(13.7, 45.3, 0)


def test_input_columns_are_the_files_own_names(tmp_path):
    """io.input_columns: the header as written (no recognition of names or units), for a CSV (pandas'
    header as the oracle), a DataFrame, a GPX file (its decoded columns) and an empty file (DataError)."""
    df = pd.DataFrame({"Track ID": ["a"], "Timestamp": ["2024-01-01T00:00:00Z"], "Lat (deg)": [45.0],
                       "Lon (deg)": [13.0], "true_lat": [45.0]})
    df.to_csv(tmp_path / "log.csv", index=False)
    assert input_columns(tmp_path / "log.csv") == list(pd.read_csv(tmp_path / "log.csv", nrows=0).columns)
    assert input_columns(df) == list(df.columns)
    assert {"lat", "lon"} <= set(input_columns(GPX))
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(DataError, match="empty"):
        input_columns(tmp_path / "empty.csv")
    with pytest.raises(ParameterError, match="^path"):
        input_columns(3)
