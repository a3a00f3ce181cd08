"""Input formats (mptrack.io._formats and the per-format readers): real files with exact values,
the structure rules of each format, and a clear DataError for every broken file.

Sample files and their sources: tests/data/formats/README.md.
"""

import gzip
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from mptrack.errors import DataError
from mptrack.io import input_format, read_table
from mptrack.io._formats import FORMATS, Skipped, raw_chunks, sniff_csv
from mptrack.tracking import track
from mptrack.cli import app

DATA = Path(__file__).parents[1] / "data"
FMT = DATA / "formats"
NMEA = FMT / "haicom-305N.nmea"          # SiRF-II, 2007, starts without a fix, then walks
NMEA_RTK = FMT / "trimble-rtk.nmea"      # Trimble at 10 Hz, DGPS then RTK fixes
FIT = FMT / "garmin-fenix-5-run.fit"     # Garmin fenix 5, 21 records
TCX = FMT / "sup_activity_1.tcx"         # stand-up paddling, two laps
GEOJSON = FMT / "walk-1.json"            # toGeoJSON output: one LineString with coordTimes
GPX_HIKE = DATA / "korita-zbevnica-hike.gpx"
GPX_BIKE = DATA / "berkelland-bike-ride.gpx"
REAL = {"gpx": DATA / "around-visnjan-with-car.gpx", "nmea": NMEA, "fit": FIT, "tcx": TCX, "geojson": GEOJSON}


def read(path, chunk_rows=100_000):
    """(all raw rows of ``path``, the Skipped records)."""
    skipped = []
    frames = list(raw_chunks(path, chunk_rows, skipped))
    return pd.concat(frames, ignore_index=True), skipped


def reasons(skipped):
    return {s.reason: s.count for s in skipped}


def utc(text):
    return pd.Timestamp(text, tz="UTC")


def minutes(deg, minute, sign=1):
    """Degrees from the NMEA ddmm.mmmm fields, computed here independently of pynmea2."""
    return sign * (deg + minute / 60.0)


# --- real files, exact values ----------------------------------------------------------------------------------

def test_nmea_real_log_combines_gga_and_rmc_and_drops_the_epochs_without_fix():
    df, skipped = read(NMEA)
    assert len(df) == 68 and set(df["track_id"]) == {"haicom-305N"}
    assert reasons(skipped) == {"NMEA epoch without a fix": 6}          # 74 epochs, the first 6 status V
    assert df["time"].iloc[0] == utc("2007-04-08T09:53:04.802")        # date of RMC, time of GGA
    assert df["time"].iloc[-1] == utc("2007-04-08T09:54:15.787")
    assert df["time"].is_monotonic_increasing
    assert df["lat"].iloc[0] == pytest.approx(minutes(27, 12.6520, -1), abs=1e-7)
    assert df["lon"].iloc[0] == pytest.approx(minutes(153, 3.1397), abs=1e-7)
    assert df["lat"].iloc[-1] == pytest.approx(minutes(27, 12.6404, -1), abs=1e-7)
    row = df.iloc[1]  # $GPGGA,095305.802,...,1,04,21.1,3.0,M  $GPRMC,...,1.93,133.96,080407
    assert (row["fix_quality"], row["satellites"], row["hdop"], row["elevation_m"]) == (1, 4, 21.1, 3.0)
    assert row["speed_mps"] == pytest.approx(1.93 * 1852 / 3600) and row["course_deg"] == 133.96


def test_nmea_real_rtk_log_keeps_eight_decimals_of_minutes():
    df, skipped = read(NMEA_RTK)
    assert len(df) == 122 and skipped == []
    assert df["time"].iloc[0] == utc("2020-03-18T13:28:19.600") and df["time"].iloc[-1] == utc("2020-03-18T13:39:01.500")
    assert df["lat"].iloc[0] == pytest.approx(minutes(41, 34.49795459), abs=1e-9)
    assert df["lon"].iloc[0] == pytest.approx(minutes(93, 45.03431408, -1), abs=1e-9)
    assert set(df["fix_quality"]) == {2.0, 4.0}  # DGPS, then RTK fixed


def test_fit_real_file_matches_the_independent_reference_table():
    """The reference CSV was written by python-fitparse's authors from the same file."""
    df, skipped = read(FIT)
    ref = pd.read_csv(FMT / "garmin-fenix-5-run-records.csv")
    assert len(df) == len(ref) == 21 and skipped == [] and set(df["track_id"]) == {"garmin-fenix-5-run"}
    assert df["time"].iloc[0] == utc("2017-06-11T14:34:09") and df["time"].iloc[-1] == utc("2017-06-11T14:35:06")
    assert str(df["time"].dtype) == "datetime64[ns, UTC]"
    assert df["lat"].iloc[0] == pytest.approx(456099128 * 180 / 2 ** 31, abs=1e-7)
    np.testing.assert_allclose(df["lat"], ref["position_lat"] * 180 / 2 ** 31, atol=1e-9)
    np.testing.assert_allclose(df["lon"], ref["position_long"] * 180 / 2 ** 31, atol=1e-9)
    np.testing.assert_allclose(df["elevation_m"], ref["altitude"], atol=1e-9)
    np.testing.assert_allclose(df["speed_mps"], ref["speed"], atol=1e-9)
    np.testing.assert_allclose(df["distance_m"], ref["distance"], atol=1e-9)
    np.testing.assert_array_equal(df["heart_rate"], ref["heart_rate"])
    np.testing.assert_array_equal(df["cadence"], ref["cadence"])
    np.testing.assert_array_equal(df["temperature"], ref["temperature"])
    assert not any(c.startswith("unknown") or c.startswith("position") for c in df.columns)


def test_tcx_real_file_concatenates_the_laps_of_the_activity():
    df, skipped = read(TCX)
    assert len(df) == 111 and skipped == []                     # 111 <Trackpoint> in 2 <Lap>
    assert set(df["track_id"]) == {"2022-07-16T16:08:25.000Z"}  # the activity's <Id>
    assert df["time"].iloc[0] == utc("2022-07-16T16:08:25") and df["time"].iloc[-1] == utc("2022-07-16T16:26:57")
    assert df["time"].iloc[98] == utc("2022-07-16T16:24:46")  # the first point of lap 2 (lap 1 has 98)
    assert df["time"].is_monotonic_increasing
    assert df["lat"].iloc[0] == pytest.approx(46.63692391477525, abs=1e-12)
    assert df["lon"].iloc[0] == pytest.approx(16.16836273111403, abs=1e-12)
    assert df["lat"].iloc[-1] == pytest.approx(46.63689751178026, abs=1e-12)
    assert (df["heart_rate"].iloc[0], df["distance_m"].iloc[0], df["speed_mps"].iloc[0]) == (96, 0.75,
                                                                                            pytest.approx(0.268))


def test_geojson_real_togeojson_line_with_coord_times():
    df, skipped = read(GEOJSON)
    assert len(df) == 423 and skipped == []
    assert set(df["track_id"]) == {"06/04/2015 Washington, District of Columbia"}   # the feature's name
    assert df["time"].iloc[0] == utc("2015-06-05T01:07:54") and df["time"].iloc[-1] == utc("2015-06-05T01:41:18")
    assert (df["lon"].iloc[0], df["lat"].iloc[0], df["elevation_m"].iloc[0]) == (-77.024365, 38.908573, 28)
    assert list(df.columns) == ["track_id", "time", "lat", "lon", "elevation_m"]  # stroke etc. are not per vertex


def test_gpx_real_hike_reports_the_empty_and_the_untimed_tracks():
    df, skipped = read(GPX_HIKE)
    assert df.groupby("track_id", sort=False).size().to_dict() == {"ACTIVE LOG": 176, "ACTIVE LOG #2": 337}
    assert reasons(skipped) == {"GPX waypoint without a time": 2, "empty GPX track": 1,
                                "GPX track without time stamps": 358}
    assert any("'03-OCT-10'" in s.detail and "no points" in s.detail for s in skipped)
    assert df["time"].iloc[0] == utc("2010-10-03T09:36:30") and df["time"].iloc[-1] == utc("2010-10-03T13:19:31")


def test_gpx_real_bike_ride_keeps_heart_rate_and_temperature_from_the_extensions():
    df, _ = read(GPX_BIKE)
    assert len(df) == 5159
    assert (df["heart_rate"].iloc[0], df["temperature"].iloc[0]) == (121, 29)
    assert df["elevation_m"].iloc[0] == pytest.approx(6.8, abs=1e-6)
    assert df["heart_rate"].notna().all()


# --- GPX structure ---------------------------------------------------------------------------------------------

GPX_HEAD = '<?xml version="1.0"?><gpx version="1.1" creator="t" xmlns="http://www.topografix.com/GPX/1/1">'


def write_gpx(tmp_path, body, name="t.gpx"):
    path = tmp_path / name
    path.write_text(GPX_HEAD + body + "</gpx>")
    return path


def pt(tag, k, time=True):
    t = f"<time>2024-05-01T10:00:{k:02d}Z</time>" if time else ""
    return f'<{tag} lat="{45 + k * 1e-4}" lon="13.5">{t}</{tag}>'


def test_gpx_tracks_routes_and_timed_waypoints_each_become_a_track(tmp_path):
    body = ("<wpt lat='45.9' lon='13.9'><time>2024-05-01T10:00:59Z</time><name>b</name></wpt>"
            "<wpt lat='45.8' lon='13.8'><time>2024-05-01T10:00:58Z</time></wpt>"
            "<wpt lat='45.7' lon='13.7'><name>no time</name></wpt>"
            f"<trk><name>Run</name><trkseg>{pt('trkpt', 1)}{pt('trkpt', 2)}</trkseg>"
            f"<trkseg>{pt('trkpt', 3)}</trkseg></trk>"
            f"<trk><trkseg>{pt('trkpt', 4)}</trkseg></trk>"
            f"<trk><name>Run</name><trkseg>{pt('trkpt', 5)}</trkseg></trk>"
            f"<rte>{pt('rtept', 6)}{pt('rtept', 7)}</rte>")
    df, skipped = read(write_gpx(tmp_path, body))
    sizes = df.groupby("track_id", sort=False).size().to_dict()
    assert sizes == {"Run": 3, "trk2": 1, "Run (2)": 1, "rte1": 2, "waypoints": 2}
    wp = df[df["track_id"] == "waypoints"]
    assert wp["lat"].tolist() == [45.8, 45.9]  # in time order
    assert reasons(skipped) == {"GPX waypoint without a time": 1}


def test_gpx_point_without_time_names_the_track_and_the_point(tmp_path):
    body = (f"<trk><name>Warm-up</name><trkseg>{pt('trkpt', 1)}</trkseg></trk>"
            f"<trk><name>Morning run</name><trkseg>"
            + "".join(pt("trkpt", k, time=k != 17) for k in range(1, 20)) + "</trkseg></trk>")
    with pytest.raises(DataError, match=r"track 'Morning run', point 17 has no time stamp") as info:
        read(write_gpx(tmp_path, body))
    assert info.value.row == 18 and info.value.column == "time" and info.value.file.name == "t.gpx"


def test_gpx_without_any_time_is_an_error_but_an_untimed_route_beside_a_track_is_skipped(tmp_path):
    with pytest.raises(DataError, match=r"route 'plan', point 1 has no time stamp, and no point"):
        read(write_gpx(tmp_path, f"<rte><name>plan</name>{pt('rtept', 1, False)}</rte>"))
    df, skipped = read(write_gpx(tmp_path, f"<rte><name>plan</name>{pt('rtept', 1, False)}{pt('rtept', 2, False)}"
                                           f"</rte><trk><trkseg>{pt('trkpt', 3)}</trkseg></trk>"))
    assert df["track_id"].tolist() == ["trk1"] and reasons(skipped) == {"GPX route without time stamps": 2}


def test_gpx_empty_track_is_reported_and_a_file_of_empty_tracks_is_an_error(tmp_path):
    df, skipped = read(write_gpx(tmp_path, f"<trk><name>e</name></trk><trk><trkseg>{pt('trkpt', 1)}</trkseg></trk>"))
    assert len(df) == 1 and skipped == [Skipped("empty GPX track", 1, f"{tmp_path / 't.gpx'}: track 'e' has no "
                                                                        "points; left out")]
    with pytest.raises(DataError, match="no track points"):
        read(write_gpx(tmp_path, "<trk><name>e</name><trkseg></trkseg></trk>"))


# --- NMEA structure --------------------------------------------------------------------------------------------

def nmea(body: str) -> str:
    """``$body*checksum``: the XOR of the characters between $ and *."""
    check = 0
    for ch in body:
        check ^= ord(ch)
    return f"${body}*{check:02X}"


def gga(hms, lat="4530.0000", quality=1):
    return nmea(f"GPGGA,{hms},{lat},N,01330.0000,E,{quality},08,0.9,12.5,M,46.9,M,,")


def rmc(hms, date="010524", status="A", lat="4530.0000"):
    return nmea(f"GPRMC,{hms},{status},{lat},N,01330.0000,E,10.0,90.0,{date},,,A")


def write(tmp_path, name, lines):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def test_nmea_date_is_carried_across_midnight_and_back_to_the_epochs_before_the_first_rmc(tmp_path):
    lines = [gga("235958.00", "4530.0010"), gga("235959.00"), rmc("235959.00", "310524"),
             gga("000000.00"), gga("000001.00")]
    df, _ = read(write(tmp_path, "night.nmea", lines))
    assert df["time"].tolist() == [utc("2024-05-31T23:59:58"), utc("2024-05-31T23:59:59"),
                                   utc("2024-06-01T00:00:00"), utc("2024-06-01T00:00:01")]
    assert df["lat"].iloc[0] == pytest.approx(45.5 + 0.001 / 60, abs=1e-9)


def test_nmea_bad_checksums_and_junk_lines_are_counted_and_a_damaged_log_is_an_error(tmp_path):
    good = [gga("100000.00"), rmc("100000.00"), gga("100001.00"), rmc("100001.00")]
    corrupt = gga("100002.00")[:-1] + ("0" if gga("100002.00")[-1] != "0" else "1")
    df, skipped = read(write(tmp_path, "a.nmea", ["# logger v1", "some text"] + good + [corrupt]))
    assert len(df) == 2
    assert reasons(skipped) == {"NMEA sentence with a bad checksum": 1, "line that is not an NMEA sentence": 1}
    assert "first: line 7" in next(s.detail for s in skipped if "checksum" in s.reason)
    with pytest.raises(DataError, match=r"3 of 4 sentences fail their checksum \(first: line 2\)"):
        read(write(tmp_path, "b.nmea", [good[0]] + [g[:-2] + "00" for g in good[1:]]))


def test_nmea_without_fix_date_or_positions_is_a_clear_error(tmp_path):
    with pytest.raises(DataError, match="no position fix in the NMEA log: all 2 epochs"):
        read(write(tmp_path, "a.nmea", [gga("100000.00", quality=0), rmc("100001.00", status="V")]))
    with pytest.raises(DataError, match="no date in the NMEA log"):
        read(write(tmp_path, "b.nmea", [gga("100000.00"), gga("100001.00")]))
    with pytest.raises(DataError, match=r"no position sentences \(GGA, RMC, GNS or GLL\).*GSV"):
        read(write(tmp_path, "c.nmea", [nmea("GPGSV,1,1,01,05,40,083,46")]))


def test_nmea_in_a_txt_file_is_recognised_by_its_content(tmp_path):
    path = write(tmp_path, "gps.txt", ["# from a phone app", rmc("100000.00"), rmc("100001.00")])
    assert input_format(path) == "nmea" and input_format(tmp_path / "x.txt") == "csv"
    assert len(read(path)[0]) == 2


# --- FIT, TCX, GeoJSON structure -------------------------------------------------------------------------------

def test_fit_truncated_file_keeps_the_records_before_the_cut(tmp_path):
    cut = tmp_path / "cut.fit"
    cut.write_bytes(FIT.read_bytes()[:3000])
    df, skipped = read(cut)
    assert 0 < len(df) < 21 and reasons(skipped) == {"FIT file truncated": 1}
    assert set(df["track_id"]) == {"cut"}
    pd.testing.assert_frame_equal(df.drop(columns="track_id"), read(FIT)[0].iloc[:len(df)][df.columns[1:]])


def test_fit_with_a_damaged_crc_is_read_and_reported(tmp_path):
    raw = bytearray(FIT.read_bytes())
    raw[-1] ^= 0xFF
    bad = tmp_path / "crc.fit"
    bad.write_bytes(bytes(raw))
    df, skipped = read(bad)
    assert len(df) == 21 and list(reasons(skipped)) == ["FIT file CRC mismatch"]


TCX_HEAD = ('<?xml version="1.0"?><TrainingCenterDatabase '
            'xmlns="http://www.garmin.com/xmlschemas/TrainingCenterDatabase/v2"><Activities>')


def tcx_point(k, position=True, time=True):
    pos = f"<Position><LatitudeDegrees>{46 + k * 1e-4}</LatitudeDegrees><LongitudeDegrees>16.1</LongitudeDegrees>" \
          "</Position>" if position else ""
    t = f"<Time>2024-05-01T10:00:{k:02d}Z</Time>" if time else ""
    return f"<Trackpoint>{t}{pos}<HeartRateBpm><Value>{100 + k}</Value></HeartRateBpm></Trackpoint>"


def write_tcx(tmp_path, activities):
    body = "".join(f"<Activity Sport='Running'><Id>{aid}</Id>"
                   + "".join(f"<Lap><Track>{''.join(lap)}</Track></Lap>" for lap in laps) + "</Activity>"
                   for aid, laps in activities)
    path = tmp_path / "a.tcx"
    path.write_text(TCX_HEAD + body + "</Activities></TrainingCenterDatabase>")
    return path


def test_tcx_one_track_per_activity_and_points_without_position_are_counted(tmp_path):
    path = write_tcx(tmp_path, [("morning", [[tcx_point(1, position=False), tcx_point(2)], [tcx_point(3)]]),
                                ("evening", [[tcx_point(4), tcx_point(5)]])])
    df, skipped = read(path)
    assert df.groupby("track_id", sort=False).size().to_dict() == {"morning": 2, "evening": 2}
    assert df["heart_rate"].tolist() == [102, 103, 104, 105]
    assert reasons(skipped) == {"TCX trackpoint without a position": 1}


def test_tcx_point_without_time_or_a_non_tcx_file_is_an_error(tmp_path):
    with pytest.raises(DataError, match=r"activity 'run', point 2 has no time stamp"):
        read(write_tcx(tmp_path, [("run", [[tcx_point(1), tcx_point(2, time=False)]])]))
    gpx_as_tcx = tmp_path / "x.tcx"
    gpx_as_tcx.write_bytes(REAL["gpx"].read_bytes())
    with pytest.raises(DataError, match=r"no track points in the TCX file: no <Activity> or <Course>"):
        read(gpx_as_tcx)


def feature(geometry, **props):
    return {"type": "Feature", "geometry": geometry, "properties": props}


def write_json(tmp_path, obj, name="f.geojson"):
    path = tmp_path / name
    path.write_text(json.dumps(obj))
    return path


def test_geojson_points_with_time_grouped_by_track_and_lines_with_per_vertex_arrays(tmp_path):
    p = lambda k, track, **kw: feature({"type": "Point", "coordinates": [13.0 + k, 45.0, 100.0 + k]},  # noqa: E731
                                       Timestamp=f"2024-05-01T10:00:0{k}+02:00", device=track, **kw)
    fc = {"type": "FeatureCollection", "features": [
        p(1, "a", accuracy_m=5), p(2, "b", accuracy_m=6), p(3, "a", accuracy_m=7),
        feature({"type": "MultiLineString", "coordinates": [[[1, 2], [1.5, 2.5]], [[2, 3]]]}, name="ride",
                coordTimes=[["2024-05-01T11:00:00Z", "2024-05-01T11:00:01Z"], ["2024-05-01T11:00:05Z"]],
                heart=[[120, 121], [125]], stroke="#f00"),
        feature({"type": "LineString", "coordinates": [[1, 2], [2, 3]]}, name="drawn"),
        feature({"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 0]]]}),
    ]}
    df, skipped = read(write_json(tmp_path, fc))
    assert df["track_id"].tolist() == ["a", "a", "b", "ride", "ride", "ride"]
    assert df["time"].iloc[0] == utc("2024-05-01T08:00:01")             # +02:00 -> UTC
    assert df["elevation_m"].iloc[:3].tolist() == [101.0, 103.0, 102.0] and df["accuracy_m"].iloc[1] == 7
    assert df["heart"].iloc[3:].tolist() == [120, 121, 125] and df["lon"].iloc[5] == 2
    assert reasons(skipped) == {"GeoJSON line without per-vertex times": 1, "GeoJSON Polygon feature": 1}


def test_geojson_errors_name_the_feature(tmp_path):
    point = {"type": "Point", "coordinates": [13, 45]}
    with pytest.raises(DataError, match=r"feature 2 \(a Point\) has no time property"):
        read(write_json(tmp_path, {"type": "FeatureCollection",
                                   "features": [feature(point, time="2024-05-01T10:00:00Z"), feature(point)]}))
    with pytest.raises(DataError, match=r"feature 1: time 'yesterday' is not an ISO 8601 time stamp"):
        read(write_json(tmp_path, feature(point, time="yesterday")))
    with pytest.raises(DataError, match=r"feature 1 \(a LineString\) has 2 vertices but 1 times in 'times'"):
        read(write_json(tmp_path, feature({"type": "LineString", "coordinates": [[1, 2], [2, 3]]},
                                          times=["2024-05-01T10:00:00Z"])))
    with pytest.raises(DataError, match=r"expected a FeatureCollection or a Feature, got 'Point'"):
        read(write_json(tmp_path, point))
    with pytest.raises(DataError, match="no timed features"):
        read(write_json(tmp_path, {"type": "FeatureCollection", "features": []}))


def test_geojson_numeric_times_are_passed_on_for_unit_detection(tmp_path):
    df, _ = read(write_json(tmp_path, feature({"type": "Point", "coordinates": [13, 45]}, time=1714557600000)))
    assert df["time"].tolist() == [1714557600000]


# --- broken files of every format ------------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", sorted(FORMATS))
def test_an_empty_file_is_a_clear_error_in_every_format(tmp_path, suffix):
    path = tmp_path / f"empty{suffix}"
    path.write_bytes(b"")
    with pytest.raises(DataError, match=r"cannot be read as .*: the file is empty \(0 bytes\)") as info:
        read(path)
    assert info.value.file == path


GARBAGE = bytes(range(256)) * 8


@pytest.mark.parametrize("suffix, message", [
    (".parquet", "cannot be read as Parquet"), (".gpx", "cannot be read as GPX"),
    (".nmea", "cannot be read as NMEA 0183: no NMEA sentence"), (".fit", "cannot be read as FIT"),
    (".tcx", "cannot be read as TCX"), (".geojson", "cannot be read as GeoJSON"),
    (".csv", "cannot be read as CSV: not UTF-8 text"),
])
def test_a_garbage_file_is_a_clear_error_in_every_format(tmp_path, suffix, message):
    path = tmp_path / f"junk{suffix}"
    path.write_bytes(GARBAGE)
    with pytest.raises(DataError, match=message) as info:
        read(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("fmt", ["gpx", "fit", "tcx", "geojson"])
def test_a_text_file_in_the_wrong_format_is_a_clear_error(tmp_path, fmt):
    path = tmp_path / f"notes.{fmt}"
    path.write_text("time,lat,lon\n2024-05-01T10:00:00Z,45,13\n")
    with pytest.raises(DataError, match="cannot be read as"):
        read(path)


# --- CSV -------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("sep", [",", ";", "\t", "|"])
def test_csv_delimiter_is_sniffed(tmp_path, sep):
    rows = [["track_id", "time", "lat", "lon"], ["a", "2024-05-01T10:00:00Z", "45.5", "13.25"],
            ["a", "2024-05-01T10:00:01Z", "45.6", "13.5"]]
    path = write(tmp_path, "f.csv", [sep.join(r) for r in rows])
    df, _ = read(path)
    assert list(df.columns) == rows[0] and df["lat"].tolist() == [45.5, 45.6]


def test_csv_bom_crlf_semicolons_and_decimal_commas(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_bytes("\ufefftime;lat;lon\r\n2024-05-01T10:00:00Z;45,5;13,25\r\n2024-05-01T10:00:01Z;45,6;13,5\r\n"
                     .encode("utf-8"))
    df, _ = read(path)
    assert list(df.columns) == ["time", "lat", "lon"] and df["lon"].tolist() == [13.25, 13.5]
    table = read_table(path)
    assert table["lat"].tolist() == [45.5, 45.6]


def test_csv_gzip_is_sniffed_after_decompression(tmp_path):
    path = tmp_path / "f.csv.gz"
    with gzip.open(path, "wt") as fh:
        fh.write("time|lat|lon\n2024-05-01T10:00:00Z|45.5|13.25\n")
    assert read(path)[0]["lat"].tolist() == [45.5]


def test_sniff_csv():
    assert sniff_csv("a,b,c\n1,2,3\n") == (",", ".")
    assert sniff_csv("a;b\n1,5;2,25\n") == (";", ",")
    assert sniff_csv("a;b\n1.5;2.25\n") == (";", ".")
    assert sniff_csv('"x,y";z\n1;2\n') == (";", ".")   # a delimiter inside quotes does not count
    assert sniff_csv("time\n1\n2\n") == (",", ".")       # one column
    assert sniff_csv("") == (",", ".")


def test_input_format_by_suffix(tmp_path):
    assert {s: input_format(tmp_path / f"x{s}") for s in (".fit", ".FIT", ".tcx", ".nmea", ".nme", ".json",
                                                           ".geojson", ".csv.gz")} == {
        ".fit": "fit", ".FIT": "fit", ".tcx": "tcx", ".nmea": "nmea", ".nme": "nmea", ".json": "geojson",
        ".geojson": "geojson", ".csv.gz": "csv"}
    with pytest.raises(DataError, match="unknown input format '.kml'"):
        input_format(tmp_path / "x.kml")


# --- end to end ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("fmt", sorted(REAL))
def test_every_format_tracks_end_to_end(fmt):
    df = track(REAL[fmt])
    raw, _ = read(REAL[fmt])
    assert len(df) == len(raw) and df["track_id"].nunique() == raw["track_id"].nunique()
    assert np.isfinite(df[["lat", "lon", "east_m", "north_m"]].to_numpy()).all()
    assert np.abs(df["lat"].to_numpy() - raw["lat"].to_numpy()).max() < 0.01  # within ~1 km of the fixes


def test_cli_tracks_a_fit_file(tmp_path):
    out = tmp_path / "run.parquet"
    res = CliRunner().invoke(app, ["track", str(FIT), "--out", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    assert pd.read_parquet(out)["track_id"].unique().tolist() == ["garmin-fenix-5-run"]
