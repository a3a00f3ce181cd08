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
