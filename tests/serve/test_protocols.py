"""The client formats of mptrack serve, parsed as the apps send them (payload shapes from the apps'
public documentation and Traccar's protocol tests), and every bad field refused by name."""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from urllib.parse import urlencode

import pytest
from _data import DATA
from hypothesis import given, settings, strategies as st

from mptrack.errors import RequestError
from mptrack.io import FIXES, read_table
from mptrack.serve._bulk import CONTENT_TYPES, parse_body as parse_bulk
from mptrack.serve._fix import FIELDS, KNOT_MPS, timestamp
from mptrack.serve._osmand import parse_query
from mptrack.serve._overland import is_batch, parse_document as parse_overland
from mptrack.serve._owntracks import device_of, parse_body as parse_owntracks
from mptrack.serve._traccar_json import parse_body as parse_traccar

NOW = 1_790_000_000.0  # 2026-09-21


def _fix(record) -> dict:
    return dict(zip(FIELDS, record))


# ---- OsmAnd / Traccar Client query strings -----------------------------------------------------------
def test_old_traccar_client_android_query():
    """ProtocolFormatter of the old Android client: speed in knots, epoch seconds, battery."""
    f, key = parse_query(b"id=861001000719969&timestamp=1767268800&lat=41.666667&lon=-0.883333&speed=10.5"
                         b"&bearing=271.5&altitude=350.06&accuracy=12.0&batt=87&mock=false", NOW)
    f = _fix(f)
    assert f["device"] == "861001000719969" and key is None
    assert f["t"] == 1767268800.0 and (f["lat"], f["lon"]) == (41.666667, -0.883333)
    assert f["speed_mps"] == pytest.approx(10.5 * 1852 / 3600) and f["heading_deg"] == 271.5
    assert f["altitude_m"] == 350.06 and f["accuracy_m"] == 12.0
    assert f["attrs"] == {"batt": 87, "mock": False}


@pytest.mark.parametrize("query, t", [
    ("id=902064&lat=42.06288&lon=-88.23412&timestamp=2016-01-27T18%3A55%3A47Z&hdop=6.0", 1453920947.0),
    ("id=902064&lat=42.06288&lon=-88.23412&timestamp=1442068686579&hdop=6.0", 1442068686.579),
    ("lat=49.60688&lon=6.15788&timestamp=2014-06-04+09%3A10%3A11&altitude=384.7&id=353861053849681", 1401873011.0),
    ("id=123456&timestamp=2026-01-01T12:00:00%2B02:00&lat=60.0&lon=30.0", 1767261600.0),
    ("id=123456&timestamp=2026-01-01T12:00:00+02:00&lat=60.0&lon=30.0", 1767261600.0),
    ("id=123456&timestamp=2026-01-01T12:00:00.5+0200&lat=60.0&lon=30.0", 1767261600.5),
    ("id=123456&timestamp=2026-01-01+12:00:00&lat=60.0&lon=30.0", 1767268800.0),
])
def test_osmand_time_forms(query, t):
    """Epoch seconds, epoch milliseconds, ISO 8601 with Z or an offset, and 'yyyy-MM-dd HH:mm:ss' (UTC); an
    offset whose "+" came unencoded (a space once the query is decoded) is still the offset."""
    assert _fix(parse_query(query, NOW)[0])["t"] == pytest.approx(t, abs=1e-6)


def test_osmand_location_deviceid_heading_cells_wifi_and_attributes():
    q = ("deviceid=abc-1&location=60.5,30.25&timestamp=1767268800&heading=12&cell=257,02,16,2224"
         "&cell=257,02,16,2223,-90&wifi=00-14-22-01-23-45,-80&ignition=true&rpm=933&fuel=24.5&note=hello&key=T0K")
    f, key = parse_query(q, NOW)
    f = _fix(f)
    assert f["device"] == "abc-1" and (f["lat"], f["lon"]) == (60.5, 30.25) and f["heading_deg"] == 12.0
    assert key == "T0K"
    assert f["attrs"] == {"ignition": True, "rpm": 933, "fuel": 24.5, "note": "hello",
                          "cells": [[257, 2, 16, 2224], [257, 2, 16, 2223, -90.0]], "wifi": [["00:14:22:01:23:45", -80.0]]}


def test_osmand_without_timestamp_takes_the_server_clock():
    assert _fix(parse_query("id=1&lat=1.5&lon=2.5", NOW)[0])["t"] == NOW


@pytest.mark.parametrize("query, field", [
    ("lat=60&lon=30&timestamp=1767268800", "id"),
    ("id=&lat=60&lon=30", "id"),
    ("id=x&lon=30", "lat"),
    ("id=x&lat=60", "lon"),
    ("id=x&lat=91&lon=30", "lat"),
    ("id=x&lat=60&lon=181", "lon"),
    ("id=x&lat=nan&lon=30", "lat"),
    ("id=x&lat=60&lon=inf", "lon"),
    ("id=x&lat=abc&lon=30", "lat"),
    ("id=x&lat=0&lon=0", "lat, lon"),
    ("id=x&lat=60&lon=30&timestamp=4070908800", "timestamp"),      # 2099
    ("id=x&lat=60&lon=30&timestamp=0", "timestamp"),               # 1970
    ("id=x&lat=60&lon=30&timestamp=315964800", "timestamp"),       # 1980, the GPS epoch
    ("id=x&lat=60&lon=30&timestamp=yesterday", "timestamp"),
    ("id=x&lat=60&lon=30&speed=fast", "speed"),
    ("id=x&lat=60&lon=30&accuracy=-inf", "accuracy"),
    ("id=x&location=60", "location"),
    ("id=x&lat=60&lon=30&cell=1,2,3", "cell"),
    ("id=x&lat=60&lon=30&wifi=aa:bb", "wifi"),
    ("id=%27%3B+DROP+TABLE+fixes%3B+--&lat=60&lon=30", "id"),
    ("id=" + "a" * 65 + "&lat=60&lon=30", "id"),
])
def test_osmand_bad_fields_are_refused_by_name(query, field):
    with pytest.raises(RequestError) as e:
        parse_query(query, NOW)
    assert e.value.field == field and e.value.status == 400, str(e.value)
    assert str(e.value).startswith(field)


def test_osmand_non_utf8_is_refused():
    with pytest.raises(RequestError, match="UTF-8"):
        parse_query(b"id=\xff&lat=1&lon=2", NOW)


# ---- Traccar Client JSON (Transistorsoft) ----------------------------------------------------------------
def _tsoft(**coords):
    c = {"latitude": 37.4219983, "longitude": -122.084, "accuracy": 5, "speed": 0, "heading": -1, "altitude": 5}
    c.update(coords)
    return {"timestamp": "2026-06-15T13:45:12.862Z", "coords": c, "is_moving": False, "odometer": 0,
            "event": "motionchange", "battery": {"level": 1, "is_charging": False}, "activity": {"type": "still"},
            "extras": {}}


def test_traccar_client_json_single_and_list():
    doc = {"device_id": "48241179", "location": _tsoft(speed=18.67, heading=63, altitude_accuracy=3.8)}
    [f] = parse_traccar(json.dumps(doc).encode(), NOW)
    f = _fix(f)
    assert f["device"] == "48241179" and f["t"] == pytest.approx(1781531112.862)
    assert f["speed_mps"] == 18.67 and f["heading_deg"] == 63 and f["accuracy_m"] == 5 and f["altitude_m"] == 5
    assert f["attrs"]["battery"] == {"level": 1, "is_charging": False} and f["attrs"]["coords"] == {
        "altitude_accuracy": 3.8}
    doc = {"device_id": "48241179", "location": [_tsoft(), _tsoft(latitude=37.5)]}
    assert [_fix(f)["lat"] for f in parse_traccar(json.dumps(doc).encode(), NOW)] == [37.4219983, 37.5]


def test_traccar_client_json_unknowns_are_negative():
    [f] = parse_traccar(json.dumps({"device_id": "1", "location": _tsoft(speed=-1, heading=-1, accuracy=-1)}).encode(),
                        NOW)
    f = _fix(f)
    assert f["speed_mps"] is None and f["heading_deg"] is None and f["accuracy_m"] is None


@pytest.mark.parametrize("body, field", [
    (b"{not json", None),
    (b'{"device_id": "1", "location": {"timestamp": "2026-01-01T00:00:00Z", "coords": {"latitude": NaN, '
     b'"longitude": 1}}}', None),
    (json.dumps({"location": _tsoft()}).encode(), "device_id"),
    (json.dumps({"device_id": "1"}).encode(), "location"),
    (json.dumps({"device_id": "1", "location": []}).encode(), "location"),
    (json.dumps({"device_id": "1", "location": {"timestamp": "2026-01-01T00:00:00Z"}}).encode(), "location.coords"),
    (json.dumps({"device_id": "1", "location": _tsoft(latitude=91)}).encode(), "location.coords.latitude"),
    (json.dumps({"device_id": "1", "location": [_tsoft(), _tsoft(longitude="x")]}).encode(),
     "location[1].coords.longitude"),
    (json.dumps({"device_id": "1", "location": dict(_tsoft(), timestamp="2099-01-01T00:00:00Z")}).encode(),
     "location.timestamp"),
    (json.dumps([1, 2]).encode(), None),
    (b"[" * 100_000, None),                       # nested past any parser's depth: refused, not a crash
])
def test_traccar_client_json_bad_input(body, field):
    with pytest.raises(RequestError) as e:
        parse_traccar(body, NOW)
    assert e.value.field == field and 400 <= e.value.status < 500, str(e.value)


# ---- Overland ----------------------------------------------------------------------------------------------
def _overland_point(lon=-122.030581, lat=37.3318, **props):
    """A point as Overland's GLManager writes it (currentDictionaryFromLocation + addMetadataToUpdate)."""
    p = {"timestamp": "2026-06-15T08:00:00-0700", "altitude": 12.5, "speed": 4.2, "course": 271.5,
         "horizontal_accuracy": 30, "vertical_accuracy": 4, "speed_accuracy": 0.5, "course_accuracy": 10,
         "motion": ["driving", "stationary"], "wifi": "", "battery_state": "charging", "battery_level": 0.89,
         "device_id": "iphone"}
    p.update(props)
    return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [lon, lat]}, "properties": p}


def test_overland_batch_as_the_app_sends_it():
    """Points in m/s and degrees, iOS's -1 for unknown, an invalid altitude dropped; the app's log entries and
    trip records queued among the points are not positions."""
    log_entry = {"type": "Feature", "geometry": {"type": "Point", "coordinates": [-122.03, 37.33]},
                 "properties": {"timestamp": "2026-06-15T15:00:03Z", "action": "paused_location_updates",
                                "battery_level": 0.8}}
    trip = {"type": "Feature", "geometry": {"type": "Point", "coordinates": [-122.03, 37.33]},
            "properties": {"type": "trip", "mode": "car", "start": "2026-06-15T14:00:00Z", "distance": 1200}}
    doc = {"locations": [_overland_point(), log_entry, trip,
                         _overland_point(lat=37.3319, timestamp="2026-06-15T15:00:05Z", speed=-1, course=-1,
                                         horizontal_accuracy=-1, vertical_accuracy=-1)],
           "current": _overland_point(lat=37.4), "trip": {"mode": "car", "distance": 1200}}
    assert is_batch(doc)
    first, second = (_fix(f) for f in parse_overland(doc, None, NOW))
    assert first["device"] == "iphone" and first["t"] == 1781535600.0   # 08:00 at -07:00
    assert (first["lat"], first["lon"]) == (37.3318, -122.030581)
    assert (first["speed_mps"], first["heading_deg"], first["accuracy_m"], first["altitude_m"]) == (4.2, 271.5, 30, 12.5)
    assert first["attrs"] == {"vertical_accuracy": 4, "speed_accuracy": 0.5, "course_accuracy": 10,
                              "motion": ["driving", "stationary"], "wifi": "", "battery_state": "charging",
                              "battery_level": 0.89}
    assert second["t"] == 1781535605.0 and second["lat"] == 37.3319
    assert (second["speed_mps"], second["heading_deg"], second["accuracy_m"], second["altitude_m"]) == (None,) * 4
    assert parse_overland({"locations": [log_entry]}, None, NOW) == []
    assert not is_batch({"device_id": "1", "location": _tsoft()})


def test_overland_device_from_the_endpoint():
    """A point without a device_id (the app's Device ID left empty) belongs to the endpoint's device."""
    doc = {"locations": [_overland_point(device_id=""), _overland_point(timestamp="2026-06-15T15:00:09Z")]}
    assert [_fix(f)["device"] for f in parse_overland(doc, "phone-2", NOW)] == ["phone-2", "iphone"]
    del doc["locations"][0]["properties"]["device_id"]
    with pytest.raises(RequestError) as e:
        parse_overland(doc, None, NOW)
    assert e.value.field == "locations[0].properties.device_id" and "?device=ID" in str(e.value)


@pytest.mark.parametrize("doc, field", [
    ({"locations": {"type": "Feature"}}, "locations"),
    ({"locations": [1]}, "locations[0].properties"),
    ({"locations": [{"type": "Feature", "properties": {"timestamp": "2026-06-15T15:00:00Z"}}]}, "locations[0].geometry"),
    ({"locations": [dict(_overland_point(), geometry={"type": "LineString", "coordinates": [[1, 2], [3, 4]]})]},
     "locations[0].geometry"),
    ({"locations": [_overland_point(), _overland_point(lat=91)]}, "locations[1].geometry.coordinates[1]"),
    ({"locations": [_overland_point(lon="x")]}, "locations[0].geometry.coordinates[0]"),
    ({"locations": [_overland_point(timestamp="yesterday")]}, "locations[0].properties.timestamp"),
    ({"locations": [_overland_point(speed="fast")]}, "locations[0].properties.speed"),
    ({"locations": [_overland_point(device_id="a b")]}, "locations[0].properties.device_id"),
])
def test_overland_bad_input(doc, field):
    with pytest.raises(RequestError) as e:
        parse_overland(doc, None, NOW)
    assert e.value.field == field and e.value.status == 400, str(e.value)


# ---- OwnTracks --------------------------------------------------------------------------------------------
def test_owntracks_location_and_other_types():
    msg = {"_type": "location", "tst": 1767268800, "acc": 10, "alt": 262, "lon": 13.60279820860699, "vac": 6,
           "vel": 18, "lat": 51.06263391678321, "cog": 82, "tid": "NE", "batt": 99, "t": "u"}
    [f] = parse_owntracks(json.dumps(msg).encode(), "jane/phone", NOW)
    f = _fix(f)
    assert f["device"] == "jane/phone" and f["t"] == 1767268800 and f["accuracy_m"] == 10
    assert f["speed_mps"] == pytest.approx(5.0) and f["heading_deg"] == 82 and f["altitude_m"] == 262
    assert f["attrs"] == {"vac": 6, "tid": "NE", "batt": 99, "t": "u"}
    assert parse_owntracks(json.dumps({"_type": "waypoint", "desc": "home"}).encode(), "jane/phone", NOW) == []
    assert parse_owntracks(json.dumps({"_type": "transition", "event": "enter"}).encode(), "jane/phone", NOW) == []
    for bad in (b"[" * 100_000, b'{"_type": "location", "lat": NaN, "lon": 1, "tst": 1767268800}'):
        with pytest.raises(RequestError, match="not valid JSON"):
            parse_owntracks(bad, "jane/phone", NOW)


@pytest.mark.parametrize("doc, code, field", [
    ({"locations": [_overland_point()]}, "wrong_endpoint", "locations"),
    ({"device_id": "1", "location": _tsoft()}, "wrong_endpoint", "location"),
    ([{"_type": "waypoint"}, {"lat": 51.0, "lon": 13.0, "tst": 1767268800}], "missing_field", "[1]._type"),
])
def test_what_is_not_owntracks_on_its_route_is_named(doc, code, field):
    """Another app pointed at /pub, or a message without _type: acknowledged as "another type" it was stored
    nowhere, and Traccar Client and Overland took the answer as delivered or resent it forever."""
    with pytest.raises(RequestError) as e:
        parse_owntracks(json.dumps(doc).encode(), "jane/phone", NOW)
    assert e.value.code == code and e.value.field == field, str(e.value)
    assert code != "wrong_endpoint" or "posts to /" in str(e.value)


def test_owntracks_device_ids():
    assert device_of("jane", "phone") == "jane/phone" and device_of("jane", None) == "jane"
    with pytest.raises(RequestError) as e:
        device_of(None, "phone")
    assert e.value.field == "u"


@pytest.mark.parametrize("msg, field", [
    ({"_type": "location", "tst": 1767268800, "lat": 51.0}, "lon"),
    ({"_type": "location", "lat": 51.0, "lon": 13.0}, "tst"),
    ({"_type": "location", "tst": 1767268800, "lat": 95.0, "lon": 13.0}, "lat"),
    ({"_type": "location", "tst": 1767268800, "lat": 51.0, "lon": 13.0, "acc": "bad"}, "acc"),
])
def test_owntracks_bad_input(msg, field):
    with pytest.raises(RequestError) as e:
        parse_owntracks(json.dumps(msg).encode(), "jane/phone", NOW)
    assert e.value.field == field


# ---- bulk -------------------------------------------------------------------------------------------------
def test_bulk_csv_and_ndjson_in_the_columns_mptrack_track_reads():
    csv = (b"device,timestamp,latitude,longitude,accuracy\n"
           b"car-1,2026-01-01T12:00:00Z,52.5,13.4,5\ncar-2,2026-01-01T12:00:01Z,48.1,11.6,\n"
           b"car-1,2026-01-01T12:00:02Z,52.50001,13.40001,6\n")
    rows = [_fix(f) for f in parse_bulk(csv, "csv", {}, NOW)]
    assert [r["device"] for r in rows] == ["car-1", "car-2", "car-1"] or sorted(r["device"] for r in rows) == \
        ["car-1", "car-1", "car-2"]
    by = {(r["device"], r["t"]): r for r in rows}
    assert by[("car-2", 1767268801.0)]["accuracy_m"] is None and by[("car-1", 1767268800.0)]["accuracy_m"] == 5
    nd = b"\n".join(json.dumps({"track_id": "t1", "time": 1767268800 + i, "lat": 52.5 + i * 1e-4, "lon": 13.4}).encode()
                    for i in range(3))
    rows = [_fix(f) for f in parse_bulk(nd, "ndjson", {}, NOW)]
    assert [r["t"] for r in rows] == [1767268800.0, 1767268801.0, 1767268802.0]


@pytest.mark.parametrize("name, ctype", [("around-visnjan-with-car.gpx", "application/gpx+xml"),
                                         ("formats/sup_activity_1.tcx", "application/vnd.garmin.tcx+xml"),
                                         ("formats/garmin-fenix-5-run.fit", "application/vnd.ant.fit"),
                                         ("formats/walk-1.json", "application/geo+json")])
def test_bulk_recorded_track_files_give_the_fixes_mptrack_track_reads(name, ctype):
    """A GPX, TCX, FIT or GeoJSON upload: the fixes read_table reads from the same file, in its order, as the
    fixes of the device ?device= names (which a file's upload needs)."""
    path = DATA / name
    want = read_table(path, FIXES)
    kind = CONTENT_TYPES[ctype]
    rows = [_fix(f) for f in parse_bulk(path.read_bytes(), kind, {"device": "rider-1"}, NOW)]
    assert [r["device"] for r in rows] == ["rider-1"] * len(want)
    assert [(r["t"], r["lat"], r["lon"]) for r in rows] == list(zip(want["t"], want["lat"], want["lon"]))
    with pytest.raises(RequestError, match="a recording's file names no device: give it as ") as e:
        parse_bulk(path.read_bytes(), kind, {}, NOW)
    assert e.value.field == "device"


def test_bulk_files_bad_input_is_named():
    gpx = CONTENT_TYPES["application/gpx+xml"]
    for body, field, text in ((b"<gpx><trk><trkseg><trkpt lat='52.5' lon='13.4'/></trkseg></trk></gpx>", "time",
                               "no time stamp"),
                              (b"not xml", None, "cannot be read as GPX"),
                              (b"", None, "the body is empty")):
        with pytest.raises(RequestError, match=text) as e:
            parse_bulk(body, gpx, {"device": "x"}, NOW)
        assert e.value.field == field and "mptrack-upload" not in str(e.value)
    with pytest.raises(RequestError) as e:
        parse_bulk(b"track_id,time,lat,lon\n", "csv", {"device": "a b"}, NOW)
    assert e.value.field == "device"
    glob = list(Path(tempfile.gettempdir()).glob("mptrack-upload-*"))
    assert glob == [], glob   # each upload's file is gone once read


_TIMES = ([1770000000, 1770000001], [1770000000000, 1770000001000], [1770000000.5, 1770000001.25],
          ["2026-02-02T02:40:00Z", "2026-02-02T02:40:01Z"], ["2026-02-02T02:40:00.5Z", "2026-02-02T02:40:01.5Z"],
          ["2026-02-02T04:40:00+02:00", "2026-02-02T04:40:01+02:00"], ["2026-02-02 02:40:00", "2026-02-02 02:40:01"])


@pytest.mark.parametrize("column", ["time", "timestamp", "date", "fix_time", "ts"])
@pytest.mark.parametrize("times", _TIMES)
@pytest.mark.parametrize("extra", [[{}, {}], [{"batt": 87, "note": "x", "charging": True}, {"batt": 86.5}],
                                   [{"cell": {"cid": 7}}, {"cell": {"lac": 3}}], [{"accuracy": "5"}, {}]])
def test_bulk_ndjson_reads_the_same_by_arrow_and_by_pandas(column, times, extra, monkeypatch):
    """Flat NDJSON goes through Arrow's reader, anything else through pandas': the same fixes either way."""
    import mptrack.serve._bulk as bulk

    body = "\n".join(json.dumps({"id": "d1", column: t, "lat": 48.1 + i * 1e-4, "lon": 11.6, "accuracy": 5, **more})
                     for i, (t, more) in enumerate(zip(times, extra))).encode()
    params = {"columns": f"time={column}"}   # pandas reads some names (date, *_time) as times itself
    fast = parse_bulk(body, "ndjson", params, NOW)
    monkeypatch.setattr(bulk, "_flat_ndjson", lambda body: None)
    assert parse_bulk(body, "ndjson", params, NOW) == fast


@pytest.mark.parametrize("body, kind, field", [
    (b"", "csv", None),
    (b"track_id,time,x,y\na,2026-01-01T00:00:00Z,1,2\n", "csv", "lat"),
    (b"track_id,time,lat,lon\na,5,52.5,13.4\na,6,52.5,13.41\n", "csv", "time"),
    (b"track_id,time,lat,lon\na,2026-01-01T00:00:00Z,95,2\n", "csv", "lat"),
    (b"track_id,time,lat,lon\na;b,2026-01-01T00:00:00Z,5,2\n", "csv", "track_id"),
    (b"track_id,time,lat,lon\na,2026-01-01T00:00:00Z,0.5,0.2\na,2026-01-01T00:00:01Z,0.5,0.21\n", "csv", "lat"),
    (b'{"track_id": "a", "time": 1767268800, "lat": 1}\n{', "ndjson", None),
    (b'{"track_id": "a\xff", "time": 1767268800, "lat": 50, "lon": 8}\n', "ndjson", None),        # not UTF-8
    (b'{"track_id": "a", "time": 1767268800, "lat": 50, "lon": 8}{"track_id": "a", "time": 1767268801, "lat": 50, '
     b'"lon": 8}\n', "ndjson", None),                                                          # two on a line
    (b'{"track_id": "a", "time": 1767268800, "lat": 50, "lon": 8, "note": "\xff"}\n', "ndjson", None),
])
def test_bulk_bad_input(body, kind, field):
    with pytest.raises(RequestError) as e:
        parse_bulk(body, kind, {}, NOW)
    assert e.value.field == field and 400 <= e.value.status < 500, str(e.value)
    assert "--" not in str(e.value)  # the server's parameters, not the command line's options


# ---- properties -------------------------------------------------------------------------------------------
@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(["id", "deviceid", "lat", "lon", "timestamp", "speed", "bearing",
                                        "accuracy", "location", "cell", "wifi", "x"]),
                       st.one_of(st.text(max_size=20), st.floats(allow_nan=True).map(str),
                                 st.integers().map(str)), max_size=8))
def test_osmand_any_query_is_a_fix_or_a_named_refusal(params):
    """Whatever the parameters, the parser returns a valid fix or a RequestError naming a field: never
    another exception, never a non-finite or out-of-range position."""
    try:
        f, _ = parse_query(urlencode(params), NOW)
    except RequestError as exc:
        assert 400 <= exc.status < 500
        return
    f = _fix(f)
    assert -90 <= f["lat"] <= 90 and -180 <= f["lon"] <= 180 and math.isfinite(f["t"])
    for k in ("accuracy_m", "speed_mps", "heading_deg", "altitude_m"):
        assert f[k] is None or math.isfinite(f[k])


def test_seconds_and_milliseconds():
    assert timestamp(1767268800, "t", NOW) == timestamp(1767268800000, "t", NOW) == 1767268800.0
    assert KNOT_MPS == pytest.approx(0.514444, rel=1e-6)


# ---- the rate limit ---------------------------------------------------------------------------------------
def test_rate_limit_buckets_by_device_key():
    """A token bucket per device key: bursts, then the average rate; a device without a key yet (its first
    fix being committed) is not limited; buckets of other devices are their own."""
    from mptrack.serve._auth import RateLimit

    limit = RateLimit(rate=2.0, burst=3.0)
    for _ in range(10):
        limit.take("new", None, now=0.0)              # no key yet: not limited
    for k in range(3):
        limit.take("dev", 5, now=100.0)
    with pytest.raises(RequestError) as e:
        limit.take("dev", 5, now=100.0)
    assert e.value.status == 429 and e.value.code == "rate_limited" and "dev " in str(e.value)
    limit.take("other", 0, n=3, now=100.0)            # another device's bucket is full
    limit.take("dev", 5, now=100.5)                   # half a second at 2 fixes/s: one token
    with pytest.raises(RequestError):
        limit.take("dev", 5, now=100.5)
    limit.take("dev", 5, n=3, now=1000.0)             # refilled to the burst, no more
    with pytest.raises(RequestError):
        limit.take("dev", 5, now=1000.0)
    with pytest.raises(RequestError):
        limit.take("dev", 5, n=50, now=1001.0)         # a batch larger than the burst waits for a full bucket
    limit.take("dev", 5, n=50, now=1002.0)             # ... and empties it (refused, it would be at every retry)
    with pytest.raises(RequestError):
        limit.take("dev", 5, now=1002.0)
    assert len(limit._level) >= 6


def test_log_throttle_says_how_many_it_held_back(monkeypatch):
    """The first line of a kind at once, then one an interval with the count held back meanwhile; kinds
    are their own."""
    from mptrack.serve import _log_throttle

    clock = [100.0]
    monkeypatch.setattr(_log_throttle.time, "monotonic", lambda: clock[0])
    t = _log_throttle.LogThrottle(60.0)
    assert t.due("encrypted") == 0
    assert t.due("encrypted") is None and t.due("encrypted", 5) is None
    assert t.due("ahead", 3) == 0                       # another kind
    clock[0] += 60.0
    assert t.due("encrypted") == 6 and t.due("encrypted") is None
