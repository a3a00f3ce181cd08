"""The live stream's queues: a client that does not read loses events, not the server's memory."""

from __future__ import annotations

import asyncio

from mptrack.serve._database import open_store
from mptrack.serve._ingest import STREAM_EVENTS, Ingest, StreamQueue
from mptrack.tracking import LiveTracks


def _batch(n: int, tag: str = "x") -> list[tuple[str, str]]:
    return [(f"d{k}", f'{{"{tag}": {k}}}') for k in range(n)]


def test_a_queue_is_bounded_by_events_and_an_empty_one_takes_any_batch():
    q = StreamQueue()
    q.offer(_batch(25_000))                  # a bulk upload's batch: an empty queue takes it whole
    q.offer(_batch(64))                      # beyond STREAM_EVENTS: dropped for this client
    assert (q.qsize(), q.events) == (1, 25_000)
    assert len(asyncio.run(q.get())) == 25_000 and q.events == 0
    for _ in range(1000):                    # OsmAnd-sized batches until the client has STREAM_EVENTS unread
        q.offer(_batch(64))
    assert q.events == 64 * (STREAM_EVENTS // 64) and q.qsize() == STREAM_EVENTS // 64


def test_a_stalled_client_of_the_ingest_holds_at_most_a_batch_beyond_the_bound(tmp_path):
    """Counted in batches (at most 1,000 a client), a client stalled during bulk uploads held every
    batch: with two such clients a server's resident memory was 895 MB after 600,000 bulk fixes and
    1,202 MB after 1.2 million (576 MB after 600,000 with none); now 591 MB after 1.2 million."""
    store = open_store(f"sqlite:///{tmp_path / 'stream.db'}")
    try:
        ingest = Ingest(store, LiveTracks())
        stalled, reading = StreamQueue(), StreamQueue()
        ingest.listen(stalled)
        ingest.listen(reading)
        got = 0
        for b in range(40):
            ingest._publish(_batch(20_000, tag=str(b)))
            got += len(asyncio.run(reading.get()))
        assert got == 40 * 20_000                          # a client that reads gets every event
        assert stalled.qsize() == 1 and stalled.events == 20_000
    finally:
        store.close()


def test_each_event_is_the_stored_estimate_of_its_fix_in_json(tmp_path):
    """A batch's stream events: one JSON object a filtered fix, its keys in the documented order, its
    numbers exactly the stored estimates (json's own text for a float), null for a missing accuracy
    and for the first fix's NIS, the flag by name and the ellipse of the stored covariance."""
    import json
    import math
    import time

    import numpy as np

    from mptrack.serve._store import FLAG_NAMES
    from mptrack.tracking import ESTIMATE_FIELDS, ellipse

    store = open_store(f"sqlite:///{tmp_path / 'stream.db'}")
    try:
        ingest = Ingest(store, LiveTracks())
        ingest.listen(StreamQueue())
        t0 = time.time() - 600
        rng = np.random.default_rng(4)
        fixes = [(f"car/{d}", t0 + 5 * k + d, 50.8 + 1e-4 * k + 1e-5 * rng.normal(), 4.35 + 1e-5 * rng.normal(),
                  None if k % 3 == 0 else 4.0 + k, None, None, None, None) for d in range(3) for k in range(8)]
        events = ingest._commit(fixes)
        assert len(events) == len(fixes)
        for d in range(3):
            rows = store.fixes(ingest.devices.get(f"car/{d}"))
            got = [json.loads(e) for dev, e in events if dev == f"car/{d}"]
            assert len(got) == len(rows) == 8
            for j, e in enumerate(got):
                assert list(e) == [*ESTIMATE_FIELDS, "device", "time", "raw_lat", "raw_lon", "accuracy_m",
                                   "ell_major_m", "ell_minor_m", "ell_azimuth_deg"]
                assert e["device"] == f"car/{d}" and e["flag"] == FLAG_NAMES[int(rows["flag"][j])]
                for key, col in (("lat", "est_lat"), ("lon", "est_lon"), ("var_e", "var_e"), ("var_n", "var_n"),
                                 ("vel_e", "vel_e"), ("vel_n", "vel_n"), ("raw_lat", "lat"), ("raw_lon", "lon")):
                    assert e[key] == rows[col][j], key
                assert (e["nis"] is None) == math.isnan(rows["nis"][j]) and (j > 0 or e["nis"] is None)
                assert (e["accuracy_m"] is None) == (j % 3 == 0)
                major, minor, az = ellipse(rows["var_e"][j:j + 1], rows["cov_en"][j:j + 1], rows["var_n"][j:j + 1])
                assert (e["ell_major_m"], e["ell_minor_m"], e["ell_azimuth_deg"]) == (major[0], minor[0], az[0])
    finally:
        store.close()
