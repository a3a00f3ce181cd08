"""The whole API fuzzed from its own /openapi.json (schemathesis, run as its users run it): no 5xx,
every 4xx a JSON error naming what is wrong, the server healthy afterwards."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from _server import Server

HOOKS = Path(__file__).with_name("_fuzz_hooks.py")


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    cells = tmp / "cells.csv"   # a cell table, so that geolocation is fuzzed beyond "not found"
    cells.write_text("radio,mcc,net,area,cell,lon,lat,range,samples,averageSignal\n"
                     "LTE,206,4,7239,103059577,4.616264,50.669577,1500,20,-95\nGSM,0,0,0,0,13.4,52.5,,,\n")
    srv = Server(tmp, "--cells", str(cells)).start()
    assert srv.get("/?id=fuzz-1&lat=52.5&lon=13.4&timestamp=1767268800").status_code == 200
    yield srv
    assert srv.stop() == 0, srv.output()


def _schemathesis(url: str, tmp: Path, *extra: str) -> subprocess.CompletedProcess:
    # the device routes get a device that exists (the generated ids are unknown ones: all 404)
    (tmp / "schemathesis.toml").write_text('[[operations]]\ninclude-path-regex = "^/api/devices/"\n'
                                           'parameters = { device_id = "fuzz-1" }\n')
    env = dict(os.environ, SCHEMATHESIS_HOOKS=HOOKS.stem, PYTHONPATH=str(HOOKS.parent))
    cmd = [sys.executable, "-m", "schemathesis.cli", "run", f"{url}/openapi.json", "--checks",
           "not_a_server_error,json_errors", "--exclude-path", "/api/stream", "--max-examples", "25", "--seed", "1",
           "--workers", "1", "--request-timeout", "60", "--no-color", *extra]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp, timeout=900)


def test_api_fuzzed_from_its_own_description(fuzzed, tmp_path):
    proc = _schemathesis(fuzzed.url, tmp_path)
    assert proc.returncode == 0, proc.stdout[-6000:] + proc.stderr[-2000:]
    assert "Missing test data" not in proc.stdout and " passed" in proc.stdout, proc.stdout[-3000:]
    assert fuzzed.get("/healthz").status_code == 200
    assert fuzzed.get("/?id=fuzz-1&lat=52.50001&lon=13.4&timestamp=1767268801").status_code == 200


def test_the_description_lists_every_route(fuzzed):
    paths = fuzzed.json("/openapi.json")["paths"]
    assert {"/", "/pub", "/api/fixes", "/healthz", "/api/devices", "/api/devices/{device_id}/position",
            "/api/devices/{device_id}/track", "/api/stream", "/api/stats", "/v1/geolocate",
            "/api/devices/{device_id}/cells"} <= set(paths)
