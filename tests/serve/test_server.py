"""mptrack serve as a real process over real sockets: every client format, real traces fed fix by fix
and queried (position, prediction, stored and smoothed track against ``mptrack track --smooth``),
late and duplicate fixes, every bad input, auth, retention, restart -- on each database backend."""

from __future__ import annotations

import base64
import io
import json
import math
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from _data import DATA, REAL_TRACES, shared_data
from _server import SRC, Server, error_of, free_port, query, stored
from conftest import BACKENDS, new_database

from mptrack.io import geodetic_to_enu, read_output, read_table

NOW = time.time()


@pytest.fixture(scope="module", params=BACKENDS)
def server(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("serve")
    # real traces are replayed as fast as the test sends them, faster than a device's rate limit lets a
    # device send (test_rate_limit has its own server)
    srv = Server(tmp, "--rate", "0", db=new_database(request.param, tmp, request)).start()
    yield srv
    assert srv.stop() == 0, srv.output()


_stored = stored


def _stats(srv) -> dict:
    return srv.json("/api/stats")


# ---- each client format, as the apps send it ---------------------------------------------------------
def test_osmand_get_and_form_post(server):
    t = int(NOW) - 600
    r = server.get(f"/?id=osm-1&timestamp={t}&lat=52.5&lon=13.4&speed=10&bearing=90&altitude=40&accuracy=8&batt=87")
    assert r.status_code == 200 and r.text == ""
    r = server.post("/", content=f"id=osm-1&timestamp={t + 5}&lat=52.50001&lon=13.4001&accuracy=8",
                    headers={"Content-Type": "application/x-www-form-urlencoded"})
    assert r.status_code == 200 and r.text == ""
    rows = _stored(server.db, "osm-1")
    assert len(rows) == 2 and rows["speed_mps"].iloc[0] == pytest.approx(10 * 1852 / 3600)
    assert json.loads(rows["attrs"].iloc[0]) == {"batt": 87}


def test_traccar_client_json(server):
    loc = {"timestamp": "2026-06-15T13:45:12.862Z", "coords": {"latitude": 37.4219983, "longitude": -122.084,
           "accuracy": 5, "speed": 3.1, "heading": 90, "altitude": 5}, "is_moving": True, "odometer": 12,
           "event": "motionchange", "battery": {"level": 0.87, "is_charging": False}, "activity": {"type": "walking"},
           "extras": {}}
    r = server.post("/", json={"device_id": "tc-1", "location": loc})
    assert r.status_code == 200
    later = dict(loc, timestamp="2026-06-15T13:45:22.862Z", coords=dict(loc["coords"], latitude=37.42205))
    r = server.post("/", json={"device_id": "tc-1", "location": [later, dict(later, timestamp="2026-06-15T13:45:32Z")]})
    assert r.status_code == 200
    rows = _stored(server.db, "tc-1")
    assert len(rows) == 3 and set(rows["speed_mps"]) == {3.1}


def _overland(lat: float, t: float, **props) -> dict:
    p = {"timestamp": time.strftime("%Y-%m-%dT%H:%M:%S-0000", time.gmtime(t)), "altitude": 40, "speed": 1.5,
         "course": 90, "horizontal_accuracy": 8, "vertical_accuracy": 3, "motion": ["walking"], "battery_level": 0.8}
    p.update(props)
    return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [13.4, lat]}, "properties": p}


def test_overland(server):
    """Overland posts its queue in batches and deletes a batch only on {"result": "ok"}; its points name the
    device, or the endpoint does (?device=)."""
    t = int(NOW) - 400
    batch = {"locations": [_overland(52.5, t, device_id="ov-1"), _overland(52.50002, t + 5, device_id="ov-1"),
                           {"type": "Feature", "properties": {"timestamp": "2026-06-15T15:00:00Z",
                                                              "action": "paused_location_updates"}}],
             "current": _overland(52.6, t + 900, device_id="ov-1")}
    r = server.post("/", json=batch)
    assert r.status_code == 200 and r.json() == {"result": "ok"}
    rows = _stored(server.db, "ov-1")
    assert len(rows) == 2 and set(rows["speed_mps"]) == {1.5} and set(rows["accuracy_m"]) == {8.0}
    r = server.post("/?device=ov-2", json={"locations": [_overland(52.5, t), _overland(52.5001, t + 5)]})
    assert r.status_code == 200 and r.json() == {"result": "ok"}
    assert len(_stored(server.db, "ov-2")) == 2
    err = error_of(server.post("/", json={"locations": [_overland(52.5, t + 10)]}))
    assert err["field"] == "locations[0].properties.device_id" and "Device ID" in err["message"]


def test_owntracks_http_mode(server):
    msg = {"_type": "location", "tst": int(NOW) - 300, "acc": 10, "alt": 262, "lon": 13.602798, "vac": 6, "vel": 18,
           "lat": 51.062634, "cog": 82, "tid": "NE", "batt": 99}
    r = server.post("/pub?u=jane&d=phone", json=msg)
    assert r.status_code == 200 and r.json() == []
    r = server.post("/pub", json=dict(msg, tst=msg["tst"] + 30), headers={"X-Limit-U": "jane", "X-Limit-D": "phone"})
    assert r.status_code == 200 and r.json() == []
    r = server.post("/pub?u=jane&d=phone", json={"_type": "waypoint", "desc": "home", "lat": 51, "lon": 13})
    assert r.status_code == 200 and r.json() == []
    rows = _stored(server.db, "jane/phone")
    assert len(rows) == 2 and rows["speed_mps"].iloc[0] == pytest.approx(5.0)
    assert server.json("/api/devices/jane/phone/position")["id"] == "jane/phone"


def test_an_encrypted_owntracks_message_is_refused_by_name_and_logged_once_a_minute(server):
    """OwnTracks takes every answer as delivered, so a refusal must reach the server's log, where the
    app's user looks; a client repeating it does not flood the log."""
    enc = {"_type": "encrypted", "data": "1Vu7OwpW4lMnh28FB+el22GsCrlnggvEcp4H8GR9iKJdi1qfwkejYpzrQ+491Mwunjg="}
    for _ in range(3):
        err = error_of(server.post("/pub?u=jane&d=sealed", json=enc))
        assert err["code"] == "encrypted" and err["field"] == "_type"
        assert "does not decrypt" in err["message"]
    assert "jane/sealed" not in [d["id"] for d in server.json("/api/devices")]
    assert _stats(server)["refused"].get("encrypted", 0) >= 3      # counted by its reason, not as "other"
    lines = [line for line in server.output().splitlines() if "refused /pub (400 encrypted): _type: " in line]
    assert len(lines) == 1 and "leave the app's encryption key empty" in lines[0], lines


def test_bulk_ndjson_and_csv(server):
    lines = [json.dumps({"device": f"gw-{i % 3}", "time": int(NOW) - 1000 + i, "latitude": 48.1 + 1e-5 * i,
                         "longitude": 11.6, "accuracy": 5}) for i in range(30)]
    r = server.post("/api/fixes", content="\n".join(lines), headers={"Content-Type": "application/x-ndjson"})
    assert r.status_code == 200 and r.json()["accepted"] == 30
    csv = "track_id,time,lat,lon\n" + "".join(f"gw-csv,{int(NOW) - 500 + i},48.2,{11.6 + 1e-5 * i}\n" for i in range(10))
    r = server.post("/api/fixes", content=csv, headers={"Content-Type": "text/csv"})
    assert r.status_code == 200 and r.json()["accepted"] == 10
    assert len(_stored(server.db, "gw-1")) == 10 and len(_stored(server.db, "gw-csv")) == 10
    # as a spreadsheet in much of Europe exports it (and mptrack track reads it): semicolons, decimal commas
    semi = "track_id;time;lat;lon\n" + "".join(f"gw-semi;{int(NOW) - 500 + i};48,2;{11.6 + 1e-5 * i:.5f}\n".replace(
        "11.", "11,") for i in range(10))
    r = server.post("/api/fixes", content=semi, headers={"Content-Type": "text/csv"})
    assert r.status_code == 200 and r.json()["accepted"] == 10, r.text
    a, b = _stored(server.db, "gw-csv"), _stored(server.db, "gw-semi")
    assert np.allclose(a[["t", "lat", "lon"]].to_numpy(), b[["t", "lat", "lon"]].to_numpy(), rtol=0, atol=1e-9)
    # how a body was read is said in the answer, the reading options named as this route's parameters
    swapped = "track_id,time,lat,lon\n" + "".join(f"gw-swap,{int(NOW) - 500 + i},{116.39 + 1e-5 * i},39.9\n"
                                                   for i in range(10))
    r = server.post("/api/fixes", content=swapped, headers={"Content-Type": "text/csv"})
    assert r.status_code == 200 and r.json()["accepted"] == 10, r.text
    notes = r.json()["notes"]
    assert any("swapped back (?columns=lat=...,lon=... to override)" in n for n in notes), notes
    assert any(n.startswith("time: epoch seconds") and n.endswith("set ?time_unit if that is wrong") for n in notes)
    assert (_stored(server.db, "gw-swap")["lat"] == 39.9).all()
    # a recording as a file (GPX here), the device named in the query
    gpx = DATA / "around-visnjan-with-car.gpx"
    r = server.post("/api/fixes?device=car-gpx", content=gpx.read_bytes(), headers={"Content-Type": "application/gpx+xml"})
    assert r.status_code == 200 and r.json()["accepted"] == len(read_table(gpx))
    assert len(_stored(server.db, "car-gpx")) == r.json()["accepted"]


# ---- late and duplicate fixes --------------------------------------------------------------------------
def test_late_fixes_are_stored_and_duplicates_are_not(server):
    t0 = int(NOW) - 3000
    before = _stats(server)
    for dt, lat in ((0, 50.0), (10, 50.0001), (20, 50.0002)):
        assert server.get(f"/?id=late-1&timestamp={t0 + dt}&lat={lat}&lon=8.0&accuracy=5").status_code == 200
    assert server.get(f"/?id=late-1&timestamp={t0 + 15}&lat=50.00015&lon=8.0&accuracy=5").status_code == 200  # late
    assert server.get(f"/?id=late-1&timestamp={t0 + 15}&lat=50.00015&lon=8.0&accuracy=5").status_code == 200  # again
    assert server.get(f"/?id=late-1&timestamp={t0 + 20}&lat=50.0002&lon=8.0&accuracy=5").status_code == 200  # repeat
    rows = _stored(server.db, "late-1").sort_values("t")
    assert list(rows["t"] - t0) == [0, 10, 15, 20]
    assert rows.loc[rows["t"] == t0 + 15, "est_lat"].isna().all()   # late: no live estimate
    after = _stats(server)
    assert after["late"] - before["late"] == 1 and after["duplicates"] - before["duplicates"] == 2
    assert server.json("/api/devices/late-1/position")["last_fix_time"].startswith(
        time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t0 + 20)))


def test_a_fix_stamped_hours_ahead_does_not_hold_up_its_device(server):
    """One fix stamped 20 h ahead (a receiver's bad time, within the day accepted) is stored with the
    history, kept out of the live filter and logged: the device's later fixes are filtered as before
    (they were all late until then); a device whose clock runs 2 h ahead all the time is filtered as any
    other."""
    t = int(time.time()) - 120
    ahead_before = _stats(server)["ahead"]

    def send(dev, tk, k):
        assert server.get(f"/?id={dev}&timestamp={tk}&lat={52.5 + k * 1e-4}&lon=13.4&accuracy=5").status_code == 200

    for k in range(5):
        send("clk-1", t + 10 * k, k)
    send("clk-1", t + 20 * 3600, 5)
    for k in range(6, 9):
        send("clk-1", t + 10 * k, k)
    flags = [f["flag"] for f in server.json("/api/devices/clk-1/track")]
    assert flags[-1] == "late" and "late" not in flags[:-1] and len(flags) == 9, flags   # the track is in time order
    assert pd.Timestamp(server.json("/api/devices/clk-1/position")["last_fix_time"]).timestamp() == t + 80
    assert _stats(server)["ahead"] == ahead_before + 1
    assert "device clk-1 sent a fix stamped" in server.output() and "kept out of its live track" in server.output()
    for k in range(6):
        send("clk-2", t + 7200 + 10 * k, k)
    assert [f["flag"] for f in server.json("/api/devices/clk-2/track")].count("late") == 0
    assert _stats(server)["ahead"] == ahead_before + 1


def test_a_device_whose_clock_is_set_back_goes_on_at_once(server):
    """A device whose last filtered fix is still hours ahead of the server's clock when fixes that are not
    come -- its clock, 2 h ahead, was set right; or its first fix, trusted, had a bad time -- has its live
    track started again from the first of them: before, all its fixes were late until the server's clock
    passed that time, and the map held it there.  A late fix of a device whose last fix is not ahead is
    still late."""
    t = int(time.time()) - 120

    def send(dev, tk, k):
        assert server.get(f"/?id={dev}&timestamp={tk}&lat={52.5 + k * 1e-4}&lon=13.5&accuracy=5").status_code == 200

    for k in range(5):
        send("back-1", t + 7200 + 10 * k, k)           # 2 h ahead all the time
    for k in range(5, 9):
        send("back-1", t + 10 * k, k)                  # then set right
    send("back-2", t + 20 * 3600, 0)                   # a first fix 20 h ahead: trusted (nothing to compare)
    for k in range(1, 4):
        send("back-2", t + 10 * k, k)
    send("back-2", t + 20 * 3600 + 60, 4)              # ahead of the clock set back: kept out
    for dev, last, n in (("back-1", t + 80, 9), ("back-2", t + 30, 5)):
        track = server.json(f"/api/devices/{dev}/track")
        flags = {round(pd.Timestamp(f["time"]).timestamp()) - t: f["flag"] for f in track}
        assert len(flags) == n, flags
        assert pd.Timestamp(server.json(f"/api/devices/{dev}/position")["last_fix_time"]).timestamp() == last
        restart = 50 if dev == "back-1" else 10
        assert flags[restart] == "init" and [f for d, f in flags.items() if d != restart].count("init") == 1, flags
        assert list(flags.values()).count("late") == (dev == "back-2"), flags
    assert "its live track starts again from this fix" in server.output()
    send("back-1", t + 75, 20)                         # the device's clock is right now: late as any other
    assert server.json("/api/devices/back-1/track", params={"from": t + 75, "to": t + 75})[0]["flag"] == "late"


def test_a_bulk_upload_of_late_fixes_is_stored_once(server):
    """A bulk batch's late fixes (a device's history uploaded after newer fixes; more than the stores write
    row by row) are stored, each exactly once: a repeat of the upload, or a fix twice in it, is not."""
    t0 = int(NOW) - 5000
    assert server.get(f"/?id=late-bulk&timestamp={t0 + 2000}&lat=50.0&lon=8.0").status_code == 200
    lines = [{"track_id": "late-bulk", "time": t0 + i, "lat": 50.0 + 1e-5 * i, "lon": 8.0} for i in range(600)]
    lines += [{"track_id": "late-bulk", "time": t0 + 700, "lat": lat, "lon": 8.0} for lat in (50.1, 50.2, 50.1)]
    body = "\n".join(json.dumps(x) for x in lines)
    before = _stats(server)
    for _ in range(2):
        r = server.post("/api/fixes", content=body, headers={"Content-Type": "application/x-ndjson"})
        assert r.status_code == 200 and r.json()["accepted"] == 603
    after = _stats(server)
    rows = _stored(server.db, "late-bulk")
    assert len(rows) == 1 + 602 and rows["est_lat"].isna().sum() == 602
    assert sorted(rows.loc[rows["t"] == t0 + 700, "lat"]) == [50.1, 50.2]
    assert after["late"] - before["late"] == 602 and after["duplicates"] - before["duplicates"] == 1 + 603


# ---- real traces fed fix by fix, then every query ----------------------------------------------------
def _traces() -> dict[str, pd.DataFrame]:
    car = read_table(REAL_TRACES["car"])
    hike = read_table(REAL_TRACES["hike"])
    bus = read_table(shared_data("receivers", "bus-304-to-UL.gpx")).iloc[:400]
    return {"car": car, "hike": hike[hike["track_id"] == "ACTIVE LOG"], "bus": bus}


@pytest.fixture(scope="module")
def fed(server, tmp_path_factory):
    """Three devices fed real GPX traces fix by fix as OsmAnd GETs (each trace also as a CSV file)."""
    tmp = tmp_path_factory.mktemp("traces")
    files = {}
    for name, df in _traces().items():
        dev = f"gpx-{name}"
        t = df["t"].to_numpy()
        lat, lon = df["lat"].to_numpy(), df["lon"].to_numpy()
        for k, (tk, la, lo) in enumerate(zip(t.tolist(), lat.tolist(), lon.tolist())):
            r = server.get(f"/?id={dev}&timestamp={int(round(tk * 1000))}&lat={la!r}&lon={lo!r}")
            assert r.status_code == 200, r.text
        path = tmp / f"{dev}.csv"
        pd.DataFrame({"track_id": dev, "time": pd.to_datetime(np.round(t * 1000).astype("int64"), unit="ms", utc=True),
                      "lat": lat, "lon": lon}).to_csv(path, index=False)
        files[dev] = path
    return files


def test_position_and_prediction_of_fed_devices(server, fed):
    """The position is the last fix's estimate, and so is its ellipse until the device's noise is estimated
    again (the estimate applied after the last fix makes the current covariance what the new noise says:
    LiveTracks.set_noise), so the ellipse is compared on a device with fewer fixes than an estimate needs."""
    car = pd.read_csv(fed["gpx-car"]).iloc[:20]
    for tk, la, lo in zip(pd.to_datetime(car["time"]).astype("int64") // 10**6, car["lat"], car["lon"]):
        assert server.get(f"/?id=gpx-car-20&timestamp={tk}&lat={la!r}&lon={lo!r}").status_code == 200
    for dev in [*fed, "gpx-car-20"]:
        live = pd.read_json(io.StringIO(server.get(f"/api/devices/{dev}/track").text))
        pos = server.json(f"/api/devices/{dev}/position")
        last = live.iloc[-1]
        assert pos["lat"] == pytest.approx(last["lat"], abs=1e-12) and pos["lon"] == pytest.approx(last["lon"], abs=1e-12)
        if dev == "gpx-car-20":
            assert pos["ell_major_m"] == pytest.approx(last["ell_major_m"], rel=1e-12)
        t_last = pd.Timestamp(pos["last_fix_time"]).timestamp()
        ahead = server.json(f"/api/devices/{dev}/position", params={"at": t_last + 30})
        assert ahead["flag"] == "predicted" and ahead["ell_major_m"] > pos["ell_major_m"]
        # the prediction moves on at the estimated velocity
        e, n = geodetic_to_enu(np.array([ahead["lat"]]), np.array([ahead["lon"]]), np.array([pos["lat"]]),
                               np.array([pos["lon"]]))
        ve, vn = last["vel_east_mps"], last["vel_north_mps"]
        assert math.hypot(e[0] - 30 * ve, n[0] - 30 * vn) < 1e-3 * max(1.0, 30 * math.hypot(ve, vn))
        past = server.get(f"/api/devices/{dev}/position", params={"at": t_last - 60})
        assert error_of(past)["field"] == "at"


@pytest.mark.parametrize("path, params, field", [
    ("position", {"at": "yesterday"}, "at"),
    ("position", {"at": int(NOW) + 3 * 86400}, "at"),
    ("track", {"from": "x"}, "from"),
    ("track", {"to": "0"}, "to"),
    ("track", {"from": int(NOW), "to": int(NOW) - 60}, "to"),
    ("track", {"format": "kml"}, "format"),
    ("track", {"smooth": "maybe"}, "smooth"),
])
def test_bad_query_parameters_are_422_naming_the_parameter(server, fed, path, params, field):
    """One status for every parameter the query API cannot take (a time it cannot read was 400 for at=,
    422 for from= and to=)."""
    r = server.get(f"/api/devices/{next(iter(fed))}/{path}", params=params)
    assert r.status_code == 422 and error_of(r)["field"] == field and error_of(r)["code"] == "invalid_field", r.text


def test_smoothed_track_equals_mptrack_track_smooth(server, fed, tmp_path):
    """track?smooth=true and ``mptrack track FILE --smooth`` on the same fixes agree to 1e-6 m."""
    for dev, path in fed.items():
        body = server.get(f"/api/devices/{dev}/track", params={"smooth": "true", "format": "parquet"}).content
        got = pd.read_parquet(io.BytesIO(body))
        out = tmp_path / f"{dev}.parquet"
        proc = subprocess.run([sys.executable, "-m", "mptrack", "track", str(path), "--smooth", "-o", str(out), "-q"],
                              capture_output=True, text=True, env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
        assert proc.returncode == 0, proc.stderr
        want = read_output(out)
        assert len(got) == len(want) == len(pd.read_csv(path))
        e, n = geodetic_to_enu(got["lat"].to_numpy(), got["lon"].to_numpy(), want["lat"].to_numpy(),
                               want["lon"].to_numpy())
        assert np.max(np.hypot(e, n)) <= 1e-6, (dev, np.max(np.hypot(e, n)))
        np.testing.assert_array_equal(got["flag"].to_numpy(), want["flag"].to_numpy())


@pytest.mark.parametrize("fmt", ["json", "geojson", "gpx", "csv", "parquet"])
def test_track_formats(server, fed, fmt, tmp_path):
    dev = "gpx-car"
    r = server.get(f"/api/devices/{dev}/track", params={"format": fmt})
    assert r.status_code == 200
    if fmt == "json":
        rows = r.json()
        assert len(rows) == 104 and {"lat", "lon", "meas_lat", "meas_lon", "flag", "ell_major_m"} <= set(rows[0])
        return
    path = tmp_path / f"t.{fmt}"
    path.write_bytes(r.content)
    back = read_output(path)
    assert len(back) == 104 and np.isfinite(back["lat"]).all()


def test_track_time_window(server, fed):
    rows = server.json("/api/devices/gpx-car/track")
    t = [pd.Timestamp(r["time"]).timestamp() for r in rows]
    some = server.json("/api/devices/gpx-car/track", params={"from": t[10], "to": t[20]})
    assert len(some) == 11
    r = server.get("/api/devices/gpx-car/track", params={"from": t[20], "to": t[10]})
    assert error_of(r)["field"] == "to"


def test_devices_list(server, fed):
    devices = {d["id"]: d for d in server.json("/api/devices")}
    assert set(fed) <= set(devices)
    assert all(np.isfinite(devices[d]["lat"]) and devices[d]["flag"] for d in fed)


# ---- bad input: a JSON 4xx naming the field, nothing stored, the server keeps serving -----------------
BAD = [
    ("GET", f"/?lat=52&lon=13&timestamp={int(NOW)}", None, None, "id"),
    ("GET", f"/?id=b&lat=91&lon=13&timestamp={int(NOW)}", None, None, "lat"),
    ("GET", f"/?id=b&lat=52&lon=181&timestamp={int(NOW)}", None, None, "lon"),
    ("GET", f"/?id=b&lat=NaN&lon=13&timestamp={int(NOW)}", None, None, "lat"),
    ("GET", f"/?id=b&lat=52&lon=Infinity&timestamp={int(NOW)}", None, None, "lon"),
    ("GET", "/?id=b&lat=52&lon=13&timestamp=4070908800", None, None, "timestamp"),   # 2099
    ("GET", "/?id=b&lat=52&lon=13&timestamp=0", None, None, "timestamp"),            # 1970
    ("POST", "/", b'{"device_id": "b", "location": {', "application/json", None),
    ("GET", f"/?id=%27%3B%20DROP%20TABLE%20fixes%3B%20--&lat=52&lon=13&timestamp={int(NOW)}", None, None, "id"),
    ("POST", "/", f"id=b&lat=52&lon=13&timestamp={int(NOW)}".encode(), "text/plain", "Content-Type"),
    ("POST", "/pub?u=jane&d=phone", b'{"_type": "location", "lat": 52, "lon": 13, "tst": "soon"}', "application/json",
     "tst"),
    ("POST", "/api/fixes", b"track_id,time,lat,lon\nb,2026-01-01T00:00:00Z,95,13\n", "text/csv", "lat"),
    ("POST", "/api/fixes", b"a,b\n1,2\n", "application/pdf", "Content-Type"),
    # an app pointed at the other app's route: named, not parsed as the wrong protocol (or dropped in silence)
    ("POST", "/", f'{{"_type": "location", "lat": 52, "lon": 13, "tst": {int(NOW)}}}'.encode(), "application/json",
     "_type"),
    ("POST", "/pub?u=jane&d=phone", b'{"locations": [{"type": "Feature", "geometry": {"type": "Point", '
     b'"coordinates": [13, 52]}, "properties": {"timestamp": "2026-01-01T00:00:00Z"}}]}', "application/json",
     "locations"),
]


@pytest.mark.parametrize("method, path, body, ctype, field", BAD, ids=[f"{i}-{b[4]}" for i, b in enumerate(BAD)])
def test_bad_input_is_refused_by_name_and_nothing_is_stored(server, method, path, body, ctype, field):
    before = len(_stored(server.db))
    headers = {"Content-Type": ctype} if ctype else {}
    r = server.post(path, content=body, headers=headers) if method == "POST" else server.get(path)
    err = error_of(r)
    assert err.get("field") == field, err
    assert len(_stored(server.db)) == before
    assert server.get("/healthz").status_code == 200
    assert query(server.db, "SELECT count(*) FROM fixes")[0][0] == before


def test_a_10_mb_body_is_refused_with_413(server):
    before = len(_stored(server.db))
    r = server.post("/api/fixes", content=b"x" * (10 << 20), headers={"Content-Type": "text/csv"})
    assert r.status_code == 413 and error_of(r)["code"] == "body_too_large"
    assert len(_stored(server.db)) == before and server.get("/healthz").status_code == 200


def test_unknown_device_and_route(server):
    assert error_of(server.get("/api/devices/nobody/position"))["code"] == "not_found"
    assert error_of(server.get("/api/nothing"))["code"] == "not_found"


# ---- operations -------------------------------------------------------------------------------------
def _metrics(srv) -> dict[str, float]:
    r = srv.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain; version=0.0.4")
    out = {}
    for line in r.text.splitlines():
        if line.startswith("#"):
            assert line.startswith(("# HELP mptrack_", "# TYPE mptrack_")), line
            continue
        name, value = line.rsplit(" ", 1)
        out[name] = float(value)
    return out


def test_metrics_in_prometheus_format(server):
    t = int(time.time()) - 10
    before = _metrics(server)
    assert server.get(f"/?id=metrics-1&timestamp={t}&lat=52.5&lon=13.4&accuracy=5").status_code == 200
    assert server.get(f"/?id=metrics-1&timestamp={t}&lat=52.5&lon=13.4&accuracy=5").status_code == 200   # repeat
    assert server.get(f"/?id=metrics-1&timestamp={t + 1}&lat=95&lon=13.4").status_code == 400
    after = _metrics(server)

    def delta(name):
        return after[name] - before.get(name, 0.0)

    assert delta("mptrack_fixes_accepted_total") == 2
    assert delta('mptrack_fixes_total{kind="filtered"}') == 1 and delta('mptrack_fixes_total{kind="duplicate"}') == 1
    assert delta('mptrack_requests_refused_total{reason="invalid_field"}') == 1
    assert delta("mptrack_ingest_request_seconds_count") == 3 and delta("mptrack_commits_total") == 2
    buckets = [v for k, v in after.items() if k.startswith("mptrack_ingest_request_seconds_bucket")]
    assert buckets == sorted(buckets) and buckets[-1] == after["mptrack_ingest_request_seconds_count"]
    assert after["mptrack_devices"] >= 1 and after["mptrack_devices_live"] >= 1
    stats = server.json("/api/stats")
    assert stats["accepted"] == after["mptrack_fixes_accepted_total"]


# ---- auth -----------------------------------------------------------------------------------------------
def _cli(*args, cwd=None) -> str:
    proc = subprocess.run([sys.executable, "-m", "mptrack", *args], capture_output=True, text=True, cwd=cwd,
                          env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


def test_auth(tmp_path, new_db):
    db = new_db()
    token = _cli("devices", "add", "car-7", "--db", db)
    other = _cli("devices", "add", "jane/phone", "--db", db)
    key = _cli("keys", "add", "dashboard", "--db", db)
    srv = Server(tmp_path, "--auth", db=db).start()
    try:
        t = int(NOW)
        q = f"/?id=car-7&lat=52.5&lon=13.4&timestamp={t}"
        assert error_of(srv.get(q))["code"] == "unauthorized"
        assert error_of(srv.get(q + "&key=wrong"))["code"] == "unauthorized"
        assert error_of(srv.get(q + f"&key={other}"))["code"] == "forbidden"  # another device's token
        assert srv.get(q + f"&key={token}").status_code == 200
        r = srv.post("/", json={"device_id": "car-7", "location": {"timestamp": t + 1, "coords": {
            "latitude": 52.5, "longitude": 13.40001}}}, headers={"Authorization": f"Bearer {token}"})
        assert r.status_code == 200
        basic = base64.b64encode(f"jane/phone:{other}".encode()).decode()
        msg = {"_type": "location", "lat": 51.0, "lon": 13.0, "tst": t}
        assert error_of(srv.post("/pub", json=msg))["code"] == "unauthorized"
        assert srv.post("/pub", json=msg, headers={"Authorization": f"Basic {basic}"}).status_code == 200
        overland = {"locations": [_overland(52.5, t + 2)]}      # no device_id: the token's device
        assert error_of(srv.post("/", json=overland))["code"] == "unauthorized"
        assert error_of(srv.post("/?device=jane/phone", json=overland, headers={
            "Authorization": f"Bearer {token}"}))["code"] == "forbidden"
        r = srv.post("/", json=overland, headers={"Authorization": f"Bearer {token}"})
        assert r.status_code == 200 and r.json() == {"result": "ok"}
        assert len(_stored(db)) == 4 and len(_stored(db, "car-7")) == 3
        assert error_of(srv.get("/api/devices"))["code"] == "unauthorized"
        assert error_of(srv.get("/"))["code"] == "unauthorized"
        assert srv.get("/api/devices", params={"key": key}).status_code == 200
        assert srv.get("/api/devices", headers={"Authorization": f"Bearer {key}"}).status_code == 200
        assert srv.get("/", params={"key": key}).status_code == 200
        assert error_of(srv.post("/api/fixes", content=b"track_id,time,lat,lon\n", headers={
            "Content-Type": "text/csv"}))["code"] == "unauthorized"
    finally:
        assert srv.stop() == 0


def _serve(*args, cwd) -> subprocess.CompletedProcess:
    """``mptrack serve ARGS`` run to its end (one that cannot start)."""
    return subprocess.run([sys.executable, "-m", "mptrack", "serve", *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd, env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})


def test_a_public_address_needs_auth(tmp_path):
    proc = _serve("--host", "0.0.0.0", "--db", f"sqlite:///{tmp_path / 'x.db'}", cwd=tmp_path)
    assert proc.returncode == 2 and "--auth" in proc.stderr


@pytest.mark.parametrize("db", ["mysql://host/db", "sqlite://relative.db"])
def test_a_database_url_of_no_known_kind_is_refused_before_the_server_starts(tmp_path, db):
    proc = _serve("--port", str(free_port()), "--db", db, cwd=tmp_path)
    assert proc.returncode == 2 and proc.stderr.strip() == (
        f"error: db: expected sqlite:///PATH or postgresql://..., got '{db}'"), proc.stderr
    assert not list(tmp_path.iterdir())


def test_a_second_server_of_one_sqlite_file_is_refused_and_a_busy_port_named(tmp_path):
    """Two servers of one SQLite file would each filter with its own live states and checkpoint over the
    other's: the second is refused (exit 2, naming the first's process), the first serves on, and once
    it has stopped the file is served again.  A port in use is named before any database is touched."""
    first = Server(tmp_path).start()
    try:
        second = _serve("--port", str(free_port()), "--db", first.db, cwd=tmp_path)
        assert second.returncode == 2, second.stderr
        assert (f"error: db: {tmp_path / 'mptrack.db'}: another run (pid {first.proc.pid}: mptrack serve) is "
                "writing it; stop that server first, or serve another database") in second.stderr
        # said once, by the command: not again in uvicorn's log lines about the failed startup
        assert second.stderr.count("another run (pid") == 1 and "startup failed" not in second.stderr, second.stderr
        assert first.get(f"/?id=car&lat=52.5&lon=13.4&timestamp={int(NOW)}").status_code == 200
        busy = _serve("--port", str(first.port), "--db", f"sqlite:///{tmp_path / 'other.db'}", cwd=tmp_path)
        assert busy.returncode == 2, busy.stderr
        assert f"error: --port: 127.0.0.1:{first.port} is in use" in busy.stderr
        assert not (tmp_path / "other.db").exists()
    finally:
        assert first.stop() == 0
    again = Server(tmp_path, db=first.db).start()
    try:
        assert [d["id"] for d in again.json("/api/devices")] == ["car"]
    finally:
        assert again.stop() == 0


def test_a_server_of_the_other_model_is_refused_by_name_and_leaves_the_database_as_it_was(tmp_path):
    """Devices tracked with cv, the server started again with --model ca: one line naming both models,
    exit 2, the database's lock released and nothing stored (the states were half loaded); cv serves on."""
    db = f"sqlite:///{tmp_path / 'mptrack.db'}"
    first = Server(tmp_path, db=db).start()
    try:
        for k in range(3):
            assert first.get(f"/?id=car&lat={52.5 + 1e-4 * k}&lon=13.4&timestamp={int(NOW) + 10 * k}").status_code == 200
    finally:
        assert first.stop() == 0
    before = query(db, "SELECT dev, state, upto FROM device_state")
    other = _serve("--port", str(free_port()), "--db", db, "--model", "ca", cwd=tmp_path)
    assert other.returncode == 2, other.stderr
    assert "error: model: the stored states are of the cv model, not ca" in other.stderr
    assert not (tmp_path / ".mptrack.db.lock").exists()
    assert query(db, "SELECT dev, state, upto FROM device_state") == before
    again = Server(tmp_path, db=db).start()
    try:
        assert again.json("/api/devices/car/position")["lat"] > 52.5
    finally:
        assert again.stop() == 0


def test_rate_limit(tmp_path, new_db):
    srv = Server(tmp_path, "--rate", "0.1", "--burst", "3", db=new_db()).start()   # one fix in 10 s after the burst
    try:
        t = int(NOW) - 100
        codes = [srv.get(f"/?id=fast&lat=52.5&lon={13.4 + k * 1e-5}&timestamp={t + k}").status_code for k in range(6)]
        assert codes[:3] == [200] * 3 and 429 in codes[3:]
        assert error_of(srv.get(f"/?id=fast&lat=52.5&lon=13.5&timestamp={t + 50}"))["code"] == "rate_limited"
    finally:
        assert srv.stop() == 0


# ---- retention and restart ------------------------------------------------------------------------------
def test_retention_and_state_across_a_restart(tmp_path, new_db):
    srv = Server(tmp_path, "--retain", "1h", db=new_db()).start()
    t = int(time.time())
    try:
        for k in range(5):
            assert srv.get(f"/?id=old&lat=52.5&lon={13.4 + k * 1e-4}&timestamp={t - 7200 + 10 * k}").status_code == 200
        for k in range(40):
            assert srv.get(f"/?id=new&lat=52.5&lon={13.4 + k * 1e-4}&timestamp={t - 400 + 10 * k}").status_code == 200
        before = srv.json("/api/devices/new/position")
    finally:
        assert srv.stop() == 0
    srv = Server(tmp_path, "--retain", "1h", "--log-format", "json", db=srv.db).start()
    try:
        deadline = time.time() + 30
        while len(_stored(srv.db, "old")) and time.time() < deadline:
            time.sleep(0.2)
        assert len(_stored(srv.db, "old")) == 0 and len(_stored(srv.db, "new")) == 40
        after = srv.json("/api/devices/new/position")
        assert after["lat"] == before["lat"] and after["lon"] == before["lon"]
        assert after["ell_major_m"] == before["ell_major_m"]
    finally:
        assert srv.stop() == 0
    # structured logs: one JSON object a line, the events with their fields
    logged = [json.loads(line) for line in srv.output().splitlines() if line.startswith("{")]
    events = {e.get("event"): e for e in logged}
    assert events["ready"]["devices"] == 2 and events["ready"]["level"] == "info", logged
    assert events["retention"]["deleted"] == 5, logged
    assert all({"time", "level", "logger", "message", "pid"} <= set(e) for e in logged), logged
