"""The cell table in the server's database, SQLite and PostgreSQL: an OpenCelliD/MLS CSV streamed in once
(one transaction, reloaded only when the file changes), its rows as the table gave them, bad and duplicate
rows counted, a server on PostgreSQL answering geolocation requests as one on SQLite does, and a
country-sized table (10^6 rows) loaded in at most 30 s and looked up in at most 1 ms."""

from __future__ import annotations

import gzip
import json
import time

import numpy as np
import pandas as pd
import pytest

from mptrack.cellular import RADIO_CODES
from mptrack.errors import DataError
from mptrack.serve._database import open_store
from mptrack.serve._celltable import load_cell_table

HEADER = "radio,mcc,net,area,cell,unit,lon,lat,range,samples,changeable,created,updated,averageSignal\n"


@pytest.fixture(scope="module")
def postgres():
    from _postgres import postgres_or_skip

    pg = postgres_or_skip()
    yield pg
    pg.cleanup()


@pytest.fixture(params=["sqlite", "postgresql"])
def new_store(request, tmp_path):
    """A function opening a new empty store of each backend (PostgreSQL: a new database on a throwaway server)."""
    opened = []

    def make():
        if request.param == "sqlite":
            store = open_store(f"sqlite:///{tmp_path / 'cells.db'}")
        else:
            pg = request.getfixturevalue("postgres")
            store = open_store(pg.create_database(f"cells{len(opened)}_{abs(hash(request.node.name)) % 10**8}"))
        opened.append(store)
        return store
    yield make
    for store in opened:
        store.close()


def test_rows_round_trip_and_bad_rows_are_counted(tmp_path, new_store):
    path = tmp_path / "cells.csv.gz"
    with gzip.open(path, "wt") as f:
        f.write(HEADER)
        f.write("LTE,206,4,7239,103059577,277,4.616264,50.669577,1500,20,1,1696809600,1762819200,-95\n")
        f.write("GSM,206,1,10,1234,,4.40,50.80,,,0,,,0\n")
        f.write("LTE,206,4,7239,103059577,277,4.7,50.7,100,2,1,,,-90\n")       # the same cell again: left out
        f.write("NBIOT,206,4,7239,5,,4.6,50.6,,,0,,,0\n")                      # a radio we do not know
        f.write("UMTS,206,4,7239,9,,4.6,95.0,,,0,,,0\n")                       # latitude out of range
    store = new_store()
    try:
        report = load_cell_table(store, path)
        assert (report.rows_read, report.cells, report.duplicates, report.areas) == (5, 2, 1, 2)
        assert sum(report.skipped.values()) == 2 and len(report.examples) == 2, report
        rows = store.find_cells([(206, 4, 7239, 103059577), (206, 1, 10, 1234), (206, 4, 7239, 5)])
        lte = next(r for r in rows if r[4] == 103059577)
        assert lte[:11] == (RADIO_CODES["LTE"], 206, 4, 7239, 103059577, 50.669577, 4.616264, 1500.0, 20.0, 1.0,
                            None)
        assert np.isfinite(lte[13])                                    # averageSignal and range: a fit
        gsm = next(r for r in rows if r[4] == 1234)
        assert gsm[13] is None                                         # averageSignal 0: unknown, no fit
        assert len(rows) == 2
        areas = store.find_cell_areas([(RADIO_CODES["LTE"], 206, 4, 7239)])
        assert len(areas) == 1 and areas[0][7:9] == (1, 1)
        # the same file again is not reloaded; a changed file is
        assert not load_cell_table(store, path).loaded
        with gzip.open(path, "wt") as f:
            f.write(HEADER + "GSM,206,1,10,1234,,4.40,50.80,,,0,,,0\n")
        assert load_cell_table(store, path).cells == 1
        assert store.find_cells([(206, 4, 7239, 103059577)]) == []
    finally:
        store.close()


def test_a_table_of_nothing_readable_is_refused_and_the_old_one_kept(tmp_path, new_store):
    good, bad = tmp_path / "good.csv", tmp_path / "bad.csv"
    good.write_text(HEADER + "GSM,206,1,10,1234,,4.40,50.80,,,0,,,0\n")
    bad.write_text(HEADER + "XX,206,1,10,1234,,4.40,50.80,,,0,,,0\n")
    store = new_store()
    try:
        load_cell_table(store, good)
        with pytest.raises(DataError, match="no cell of the table could be read"):
            load_cell_table(store, bad)
        assert len(store.find_cells([(206, 1, 10, 1234)])) == 1
    finally:
        store.close()


def test_cells_the_position_model_cannot_take_are_not_used(tmp_path, new_store):
    """A cell the table may hold but the position from cells cannot use (within 5 degrees of a pole) counts as
    unknown: the other cells of the request are used, alone it gets the area's fallback (it was a 500)."""
    from mptrack.serve._geolocate import Geolocator, parse_request

    path = tmp_path / "cells.csv"
    path.write_text(HEADER + "GSM,206,1,10,1234,,4.40,50.80,,,0,,,-80\n" + "GSM,206,1,11,77,,20.0,87.5,,,0,,,-80\n")
    store = new_store()
    try:
        load_cell_table(store, path)
        geo = Geolocator(store)

        def request(*cells):
            return parse_request(json.dumps({"cellTowers": [
                {"radioType": "gsm", "mobileCountryCode": 206, "mobileNetworkCode": 1, "locationAreaCode": area,
                 "cellId": cell, "signalStrength": -80} for area, cell in cells]}).encode())
        both = geo.locate(request((11, 77), (10, 1234)))
        assert (both.known, both.unknown, both.fallback) == (1, 1, None) and abs(both.lat - 50.8) < 0.1
        polar = geo.locate(request((11, 77)))
        assert (polar.fallback, polar.lat) == ("lacf", 87.5)
    finally:
        store.close()


def test_concurrent_answers_are_each_requests_own_and_a_closed_geolocator_fails_them(tmp_path):
    """Geolocator.answer computes the requests that gather together: each gets what locate gives it alone;
    once closed, a request fails at once instead of waiting for ever."""
    import asyncio

    from mptrack.serve._geolocate import Geolocator, parse_request

    path = tmp_path / "cells.csv"
    path.write_text(HEADER + "".join(f"GSM,206,1,10,{c},,{4.40 + 0.01 * c},{50.80 + 0.005 * c},,,0,,,-80\n"
                                     for c in range(1, 6)))
    store = open_store(f"sqlite:///{tmp_path / 'cells.db'}")
    try:
        load_cell_table(store, path)
        geo = Geolocator(store)
        queries = [parse_request(json.dumps({"cellTowers": [
            {"radioType": "gsm", "mobileCountryCode": 206, "mobileNetworkCode": 1, "locationAreaCode": 10,
             "cellId": c, "signalStrength": level} for c, level in zip(cells, (-70, -85, -95))]}).encode())
            for cells in ((1, 2, 3), (2, 3, 4), (3, 4, 5), (5, 1, 2), (4,), (1, 5))]
        alone = [geo.locate(q) for q in queries]

        async def together():
            return await asyncio.gather(*(geo.answer(q) for q in queries * 5))
        assert asyncio.run(together()) == alone * 5
        geo.close()
        for q in queries[:2]:
            with pytest.raises(RuntimeError):
                asyncio.run(asyncio.wait_for(geo.answer(q), 10.0))
    finally:
        store.close()


@pytest.mark.slow
def test_a_million_cells_load_in_30_s_and_look_up_in_1_ms(tmp_path):
    n = 1_000_000
    rng = np.random.default_rng(7)
    radio = rng.choice(["GSM", "UMTS", "LTE"], n, p=[0.3, 0.2, 0.5])
    table = pd.DataFrame({"radio": radio, "mcc": 262, "net": rng.integers(1, 4, n), "area": rng.integers(1, 5000, n),
                          "cell": rng.permutation(n) * 7 + 1, "unit": rng.integers(0, 504, n),
                          "lon": rng.uniform(6.0, 15.0, n).round(6), "lat": rng.uniform(47.5, 55.0, n).round(6),
                          "range": rng.integers(100, 20000, n), "samples": rng.integers(1, 500, n),
                          "changeable": 1, "created": 1_500_000_000, "updated": 1_700_000_000,
                          "averageSignal": rng.integers(-110, -60, n)})
    path = tmp_path / "cell_towers.csv.gz"
    table.to_csv(path, index=False, compression="gzip")
    store = open_store(f"sqlite:///{tmp_path / 'cells.db'}")
    try:
        t0 = time.perf_counter()
        report = load_cell_table(store, path)
        load_s = time.perf_counter() - t0
        assert report.cells == n
        keys = [(262, int(r.net), int(r.area), int(r.cell)) for r in table.sample(2000, random_state=1).itertuples()]
        store.find_cells(keys[:1])                                      # the reader's connection
        times = []
        for k in keys:
            t0 = time.perf_counter()
            rows = store.find_cells([k])
            times.append(time.perf_counter() - t0)
            assert len(rows) == 1 and rows[0][4] == k[3]
        print(f"load {load_s:.1f} s, lookup median {np.median(times) * 1e6:.0f} us, p99 "
              f"{np.percentile(times, 99) * 1e6:.0f} us")
        assert load_s <= 30.0
        assert np.median(times) <= 1e-3
    finally:
        store.close()


def test_a_server_on_postgresql_answers_as_one_on_sqlite(tmp_path, postgres):
    """The same geolocation requests (the real walks' first scans and the error cases) answered by a server whose
    database is PostgreSQL and by the offline twin on SQLite: the same answers."""
    import httpx
    from _geolocation import real_requests
    from _server import Server

    from mptrack.serve import geolocate_requests

    bodies, _, cells = real_requests()
    bodies = bodies[:60] + [{"cellTowers": [{"radioType": "lte", "mobileCountryCode": 206, "mobileNetworkCode": 4,
                                             "locationAreaCode": 7239, "cellId": 5}]}, {}]
    requests = tmp_path / "requests.ndjson"
    requests.write_text("".join(json.dumps(b) + "\n" for b in bodies))
    expected = [(status, answer) for _, status, answer in geolocate_requests(requests, cells=cells)]
    assert [s for s, _ in expected].count(200) == 61                 # the real scans and the area fallback
    srv = Server(tmp_path, "--cells", str(cells), db=postgres.create_database("geolocate")).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60.0) as client:
            got = [(r.status_code, r.json()) for r in (client.post("/v1/geolocate", json=b) for b in bodies)]
    finally:
        assert srv.stop() == 0, srv.output()
    assert got == expected
