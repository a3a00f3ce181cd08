"""Cell geolocation (issue 32) on a real server on loopback: ``POST /v1/geolocate`` answering requests built
from the shipped real LTE walks and from a simulated multi-site network, against Mozilla's weighted
centroid written in the test from its published description (tests/_geolocation.py); the accuracy's
68 % coverage; every error case in Google's format; devices that report cells instead of positions; the
offline twin ``mptrack geolocate`` giving the same answers, as do concurrent requests."""

from __future__ import annotations

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np
import pandas as pd
import pytest
from _geolocation import distance_m, real_requests, simulated_requests, write_ndjson
from _server import Server

LEVEL = 0.68


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """The real walks' requests and a simulated network's, and one cell table holding both (MCC 206 / 999)."""
    tmp = tmp_path_factory.mktemp("geolocate")
    real, real_truth, real_cells = real_requests()
    sim, sim_truth, sim_table = simulated_requests(seed=11, oracle=True)
    noaz, noaz_truth, noaz_table = simulated_requests(seed=12, azimuth=False, mcc=998)
    omni, omni_truth, omni_table = simulated_requests(seed=13, sectors=False, mcc=997, oracle=True)
    table = pd.concat([pd.read_csv(real_cells), sim_table, noaz_table, omni_table], ignore_index=True)
    cells = tmp / "cells.csv.gz"
    table.to_csv(cells, index=False)
    return {"tmp": tmp, "cells": cells, "real": real, "real_truth": real_truth, "sim": sim, "sim_truth": sim_truth,
            "noaz": noaz, "noaz_truth": noaz_truth, "omni": omni, "omni_truth": omni_truth}


@pytest.fixture(scope="module")
def server(data):
    srv = Server(data["tmp"], "--cells", str(data["cells"])).start()
    yield srv
    assert srv.stop() == 0, srv.output()


def _answers(srv: Server, bodies: list[dict]) -> np.ndarray:
    out = []
    with httpx.Client(base_url=srv.url, timeout=60.0) as client:
        for b in bodies:
            r = client.post("/v1/geolocate", json=b)
            assert r.status_code == 200, r.text
            a = r.json()
            assert set(a) == {"location", "accuracy"}, a
            out.append((a["location"]["lat"], a["location"]["lng"], a["accuracy"]))
    return np.array(out)


def _report(name: str, err: np.ndarray, ref: np.ndarray, acc: np.ndarray, truth: pd.DataFrame | None = None) -> dict:
    stats = {"median": np.median(err), "p90": np.percentile(err, 90), "ref_median": np.median(ref),
             "ref_p90": np.percentile(ref, 90), "coverage": np.mean(err <= acc)}
    if truth is not None and "oracle_lat" in truth and truth.oracle_lat.notna().all():
        stats["oracle_median"] = np.median(distance_m(truth.oracle_lat, truth.oracle_lon, truth.lat, truth.lon))
    print(name, {k: round(float(v), 3) for k, v in stats.items()})
    return stats


def test_real_walks(server, data):
    """The 953 scans of the real walks (one site per area: the weighted centroid is that site): no worse than the
    centroid, and the accuracy holds the truth in 68 +- 5 % of the scans."""
    ans = _answers(server, data["real"])
    t = data["real_truth"]
    err = distance_m(ans[:, 0], ans[:, 1], t.lat, t.lon)
    ref = distance_m(t.ref_lat, t.ref_lon, t.lat, t.lon)
    s = _report("real", err, ref, ans[:, 2])
    assert s["median"] <= s["ref_median"] + 1.0 and s["p90"] <= s["ref_p90"] + 1.0
    assert abs(s["coverage"] - LEVEL) <= 0.05
    for place in ("ixelle", "lln", "waha"):  # each place on its own: never worse than its site
        sel = (t.place == place).to_numpy()
        assert np.median(err[sel]) <= np.median(ref[sel]) + 1.0, place


def test_simulated_network(server, data):
    """A simulated 19-site network of three-sector sites, transmit powers and heights unknown, 8 dB shadowing,
    the cell table crowd-sourced with the sectors' azimuths: the median error at most 0.8 x the weighted
    centroid's (a posterior mean that knows every transmitter exactly reaches about 0.4 x).  The accuracy
    errs on the safe side here: the model expects a sector to serve off its axis as often as the real walks
    show (Ixelles), the simulated sectors never do."""
    ans = _answers(server, data["sim"])
    t = data["sim_truth"]
    err = distance_m(ans[:, 0], ans[:, 1], t.lat, t.lon)
    ref = distance_m(t.ref_lat, t.ref_lon, t.lat, t.lon)
    s = _report("simulated", err, ref, ans[:, 2], t)
    assert s["oracle_median"] < s["median"] <= 0.8 * s["ref_median"]
    assert s["p90"] <= 0.85 * s["ref_p90"]
    assert LEVEL - 0.05 <= s["coverage"] <= LEVEL + 0.12


def test_simulated_network_without_azimuths(server, data):
    """The same kind of network with an OpenCelliD-like table (no azimuths): better than the centroid (0.83 x
    here: 0.88 x while the serving sector's loss off its axis was taken for noise, every range ~25 % too long),
    and the accuracy holds the truth in 68 +- 5 % of the requests."""
    ans = _answers(server, data["noaz"])
    t = data["noaz_truth"]
    err = distance_m(ans[:, 0], ans[:, 1], t.lat, t.lon)
    ref = distance_m(t.ref_lat, t.ref_lon, t.lat, t.lon)
    s = _report("simulated, no azimuths", err, ref, ans[:, 2])
    assert s["median"] <= 0.85 * s["ref_median"] and s["p90"] <= 0.95 * s["ref_p90"]
    assert abs(s["coverage"] - LEVEL) <= 0.05


def test_simulated_network_of_omnidirectional_cells(server, data):
    """Three omnidirectional cells a site (one shadowing per site, so a scan ranges to two or three sites): even
    the posterior mean that knows every transmitter exactly is only about 0.86 x the centroid here, so the
    issue's 0.8 x cannot be reached; ours is no worse than the centroid, and its accuracy errs on the safe side
    (the prior allows environments the simulation does not draw)."""
    ans = _answers(server, data["omni"])
    t = data["omni_truth"]
    err = distance_m(ans[:, 0], ans[:, 1], t.lat, t.lon)
    ref = distance_m(t.ref_lat, t.ref_lon, t.lat, t.lon)
    s = _report("simulated, omnidirectional", err, ref, ans[:, 2], t)
    assert s["oracle_median"] > 0.8 * s["ref_median"]             # the goal is out of any method's reach here
    assert s["oracle_median"] < s["median"] <= s["ref_median"] and s["p90"] <= 1.05 * s["ref_p90"]
    assert LEVEL - 0.05 <= s["coverage"] <= LEVEL + 0.2


def test_offline_twin_gives_the_servers_answers(server, data):
    """``mptrack geolocate requests.ndjson --cells FILE`` answers every request as the server does."""
    bodies = data["real"][:40] + data["sim"][:40] + [{"cellTowers": [{"cellId": "x"}]}, {}]
    path = write_ndjson(data["tmp"] / "requests.ndjson", bodies)
    out = data["tmp"] / "answers.ndjson"
    proc = subprocess.run([sys.executable, "-m", "mptrack", "geolocate", str(path), "--cells", str(data["cells"]),
                           "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "82 requests: 80 located, 1 not found, 1 refused" in proc.stderr
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert [x["line"] for x in lines] == list(range(1, 83))
    expected = [(line.pop("status"), {k: v for k, v in line.items() if k != "line"}) for line in lines]
    with httpx.Client(base_url=server.url, timeout=60.0) as client:
        for body, want in zip(bodies, expected):
            r = client.post("/v1/geolocate", json=body)
            assert (r.status_code, r.json()) == want

        def post(body):
            r = client.post("/v1/geolocate", json=body)
            return r.status_code, r.json()

        # concurrent requests are located together (one call of the compiled kernel): each its own answer
        with ThreadPoolExecutor(16) as pool:
            assert list(pool.map(post, bodies * 3)) == expected * 3


def _google_error(r: httpx.Response, status: int, reason: str) -> str:
    assert r.status_code == status, (r.status_code, r.text)
    body = r.json()
    assert set(body) == {"error"} and set(body["error"]) == {"errors", "code", "message"}, body
    assert body["error"]["code"] == status and len(body["error"]["errors"]) == 1
    e = body["error"]["errors"][0]
    assert e["reason"] == reason and e["message"] == body["error"]["message"], body
    assert e["domain"] == {"parseError": "global", "notFound": "geolocation", "keyInvalid": "usageLimits"}[reason]
    return e["message"]


CELL = {"radioType": "lte", "mobileCountryCode": 206, "mobileNetworkCode": 4, "locationAreaCode": 7239,
        "cellId": 103059577, "signalStrength": -96}


@pytest.mark.parametrize("body, field", [
    (b"{", "not JSON"),
    (b"[" * 100_000, "not JSON"),                 # nested past any parser's depth: refused, not a crash
    (json.dumps({"cellTowers": [CELL]}).replace("-96", "NaN").encode(), "not JSON"),
    (b"[1, 2]", "expected a JSON object"),
    (json.dumps({"cellTowers": {"cellId": 1}}).encode(), "cellTowers: expected a list"),
    (json.dumps({"cellTowers": [5]}).encode(), "cellTowers[0]: expected an object"),
    (json.dumps({"radioType": "5g"}).encode(), "radioType: expected one of gsm, wcdma, lte, nr, cdma"),
    (json.dumps({"cellTowers": [{**CELL, "cellId": "103059577"}]}).encode(), "cellTowers[0].cellId: expected an integer"),
    (json.dumps({"cellTowers": [{**CELL, "cellId": 1 << 28}]}).encode(), "cellTowers[0].cellId: expected 0..268435455"),
    (json.dumps({"cellTowers": [{**CELL, "radioType": "gsm", "cellId": 70000}]}).encode(),
     "cellTowers[0].cellId: expected 0..65535"),
    (json.dumps({"cellTowers": [{**CELL, "mobileCountryCode": 1000}]}).encode(),
     "cellTowers[0].mobileCountryCode: expected 0..999"),
    (json.dumps({"cellTowers": [{**CELL, "signalStrength": 25}]}).encode(), "cellTowers[0].signalStrength: expected dBm"),
    (json.dumps({"cellTowers": [{**CELL, "timingAdvance": 2000}]}).encode(), "cellTowers[0].timingAdvance: expected 0..1282"),
    (json.dumps({"cellTowers": [{**CELL, "radioType": "nr", "cellId": 5}]}).encode(),
     "cellTowers[0].cellId: an NR cell's identity is newRadioCellId"),
    (json.dumps({"cellTowers": [CELL] * 65}).encode(), "cellTowers: at most 64 cells"),
    (json.dumps({"considerIp": "yes"}).encode(), "considerIp: expected true or false"),
    (json.dumps({"fallbacks": {"lacf": 1}}).encode(), "fallbacks.lacf: expected true or false"),
])
def test_bad_requests_are_parse_errors_naming_the_field(server, body, field):
    message = _google_error(httpx.post(server.url + "/v1/geolocate", content=body, timeout=60), 400, "parseError")
    assert field in message, message


def test_not_found_and_the_area_fallback(server):
    unknown = {**CELL, "cellId": 12345}
    # nothing known: 404 in Google's format (an empty request, and a cell the table does not have without lacf)
    _google_error(httpx.post(server.url + "/v1/geolocate", json={}, timeout=60), 404, "notFound")
    _google_error(httpx.post(server.url + "/v1/geolocate", json={"cellTowers": [unknown], "fallbacks": {"lacf": False}},
                             timeout=60), 404, "notFound")
    # its area is known: the area's centre, marked as a fallback, with the area's radius
    r = httpx.post(server.url + "/v1/geolocate", json={"cellTowers": [unknown]}, timeout=60)
    assert r.status_code == 200 and r.json()["fallback"] == "lacf" and r.json()["accuracy"] >= 800.0
    # cells without their full identity (Android's "unavailable") are left out, as Ichnaea does; Wi-Fi ignored
    body = {"cellTowers": [CELL, {**CELL, "cellId": 2147483647}, {"radioType": "lte"}],
            "wifiAccessPoints": [{"macAddress": "01:23:45:67:89:ab"}]}
    r = httpx.post(server.url + "/v1/geolocate", json=body, timeout=60)
    assert r.status_code == 200 and "fallback" not in r.json()
    stats = server.json("/api/stats")["geolocate"]
    assert stats["cells_incomplete"] >= 2 and stats["wifi_ignored"] >= 1 and stats["not_found"] >= 2


def test_devices_that_report_cells_get_a_track(server):
    """An OsmAnd report with cells and no position, and a geolocate body posted for a device, are placed from the
    cell table and feed the device's live track, mixed with its GPS fixes."""
    t0 = 1_767_268_800
    r = httpx.get(f"{server.url}/?id=cellphone&timestamp={t0}&cell=206,4,7239,103059577,-96", timeout=60)
    assert r.status_code == 200, r.text
    pos = server.json("/api/devices/cellphone/position")
    assert distance_m(pos["lat"], pos["lon"], 50.669576891, 4.616264081) < 5.0   # one site: its centre
    assert 300.0 < pos["ell_major_m"] < 2000.0                                     # ... with the cell's spread
    # a GPS fix 400 m from the site then pulls the track to it (its accuracy is 5 m)
    r = httpx.get(f"{server.url}/?id=cellphone&timestamp={t0 + 10}&lat=50.6720&lon=4.6210&accuracy=5", timeout=60)
    assert r.status_code == 200
    pos = server.json("/api/devices/cellphone/position")
    assert distance_m(pos["lat"], pos["lon"], 50.6720, 4.6210) < 20.0
    # a device posting its cells
    r = httpx.post(f"{server.url}/api/devices/walker/cells", json={"timestamp": t0, "cellTowers": [CELL]}, timeout=60)
    assert r.status_code == 200 and set(r.json()) == {"location", "accuracy"}
    walker = [d for d in server.json("/api/devices") if d["id"] == "walker"]
    assert len(walker) == 1 and distance_m(walker[0]["raw_lat"], walker[0]["raw_lon"], 50.669576891, 4.616264081) < 5
    # unknown cells: 404, nothing stored; no cells and no position: the OsmAnd error names the latitude
    r = httpx.get(f"{server.url}/?id=cellphone&timestamp={t0 + 20}&cell=206,4,1,1", timeout=60)
    assert r.status_code == 404 and r.json()["error"]["code"] == "notFound", r.text
    r = httpx.get(f"{server.url}/?id=cellphone&timestamp={t0 + 20}&batt=50", timeout=60)
    assert r.status_code == 400 and r.json()["error"]["field"] == "lat", r.text


def test_keys_with_auth(tmp_path, data):
    """With --auth a geolocate request needs an API key: a missing or unknown one is Google's 400 keyInvalid."""
    db = tmp_path / "mptrack.db"
    key = subprocess.run([sys.executable, "-m", "mptrack", "keys", "add", "app", "--db", f"sqlite:///{db}"],
                         capture_output=True, text=True, check=True).stdout.strip()
    srv = Server(tmp_path, "--auth", "--cells", str(data["cells"]), db=db).start()
    try:
        _google_error(httpx.post(srv.url + "/v1/geolocate", json={"cellTowers": [CELL]}, timeout=60), 400, "keyInvalid")
        _google_error(httpx.post(srv.url + "/v1/geolocate?key=nope", json={"cellTowers": [CELL]}, timeout=60), 400,
                      "keyInvalid")
        r = httpx.post(srv.url + f"/v1/geolocate?key={key}", json={"cellTowers": [CELL]}, timeout=60)
        assert r.status_code == 200, r.text
    finally:
        assert srv.stop() == 0, srv.output()
