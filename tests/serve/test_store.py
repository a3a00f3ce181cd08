"""The store interface on both backends: what the live filter's noise estimate reads back."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import new_database

from mptrack.serve._database import open_store
from mptrack.serve._store import LATE, stored_rows


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_histories_are_each_devices_last_filtered_fixes_in_time_order(backend, tmp_path, request):
    store = open_store(new_database(backend, tmp_path, request))
    try:
        keys = dict((d, k) for k, d in store.register(["a", "b", "c"]))

        def rows(dev, times, flag, accuracy=None):
            return stored_rows([(0, dev, t, 50.0 + t * 1e-6, 8.0, accuracy, None, None, None, None, t, 50.0, 8.0,
                                 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, flag) for t in times])

        a, b = keys["a"], keys["b"]
        with store.batch(np.array(sorted([a, b])), np.zeros(2, np.int64)) as tx:
            tx.write(rows(a, [1e9 + k for k in range(0, 20, 2)], 0, accuracy=5.0))
        with store.batch(np.array(sorted([a, b])), np.zeros(2, np.int64)) as tx:
            tx.write(rows(b, [2e9 + k for k in range(5)], 0), rows(a, [1e9 + 7.0, 1e9 + 21.0], LATE))
        got = store.histories([b, keys["c"], a], 4)
        assert [h.shape for h in got] == [(4, 4), (0, 4), (4, 4)]
        assert got[0][:, 0].tolist() == [2e9 + 1, 2e9 + 2, 2e9 + 3, 2e9 + 4] and np.isnan(got[0][:, 3]).all()
        assert got[2][:, 0].tolist() == [1e9 + 12, 1e9 + 14, 1e9 + 16, 1e9 + 18]   # the late fixes left out
        assert got[2][:, 1].tolist() == [50.0 + t * 1e-6 for t in got[2][:, 0]] and (got[2][:, 3] == 5.0).all()
    finally:
        store.close()


def test_noise_is_estimated_again_as_a_device_gathers_fixes(tmp_path, monkeypatch):
    """A device's noise is estimated after calibrate_after fixes, then again once it has RENEW times as
    many new fixes as the last estimate used: a long history is not read again every 30 fixes."""
    import asyncio

    from mptrack.serve import _ingest
    from mptrack.serve._ingest import RENEW, Ingest
    from mptrack.tracking import LiveTracks

    monkeypatch.setattr(_ingest, "ROUND_MIN", 1)   # one device: its rounds as soon as it is due

    store = open_store(f"sqlite:///{tmp_path / 'noise.db'}")
    ingest = Ingest(store, LiveTracks(), calibrate_after=30, history_fixes=400)
    fed, estimates = [0], []                      # (fixes fed when an estimate started, fixes it used)
    estimate = ingest._estimate

    def recorded(due):
        out = estimate(due)
        if 0 in due:
            estimates.append((fed[0], int(out[2][list(due).index(0)])))
        return out

    ingest._estimate = recorded

    async def feed():
        ingest.start()
        rng = np.random.default_rng(5)
        for k in range(0, 1500, 10):
            t = 1.77e9 + np.arange(k, k + 10, dtype=float)
            lat = 50.0 + 1e-5 * np.arange(k, k + 10) + rng.normal(0, 3e-5, 10)
            await ingest.submit([("walker", tk, la, 8.0, 5.0, None, None, None, None) for tk, la in zip(t, lat)])
            fed[0] = k + 10
            if ingest._estimating is not None:
                ingest._estimating.result()          # this round's estimate, applied with the next batch
        await ingest.close()

    try:
        asyncio.run(feed())
    finally:
        store.close()
    at, used = np.array(estimates).T
    assert used[0] >= 30 and used[-1] == 400 and (at[-1] >= 1400)   # estimated to the end, the window full
    assert (np.diff(at) >= np.maximum(30, RENEW * used[:-1]) - 10).all()
    assert len(at) < 1500 / 30 / 2                                  # not every 30 fixes


def test_noise_estimates_take_at_most_their_share_of_a_core(tmp_path, monkeypatch):
    """While a device stays due (every batch brings it enough new fixes), a noise round starts only after a
    rest of (1 / ESTIMATOR_SHARE - 1) times the round before; closing does not wait for the rest."""
    import asyncio
    import time

    from mptrack.serve import _ingest
    from mptrack.serve._ingest import ESTIMATOR_SHARE, Ingest
    from mptrack.tracking import LiveTracks

    monkeypatch.setattr(_ingest, "ROUND_MIN", 1)

    store = open_store(f"sqlite:///{tmp_path / 'share.db'}")
    ingest = Ingest(store, LiveTracks(), calibrate_after=30)
    estimate, rounds = ingest.estimates.estimate, []

    closing_round = []

    def slow(devices):                            # a round that takes 0.2 s
        (closing_round if ingest._stopping.is_set() else rounds).append(time.monotonic())
        started = time.monotonic()
        out = estimate(devices)
        time.sleep(max(0.0, 0.2 - (time.monotonic() - started)))
        return out

    estimate([])                                  # the process started before the rounds are timed
    ingest.estimates.estimate = slow

    async def feed():
        ingest.start()
        t = 1.77e9
        until = time.monotonic() + 2.5
        while time.monotonic() < until:           # 30 new fixes a batch: the device is always due
            await ingest.submit([("walker", t + i, 50.0 + 1e-5 * i, 8.0, 5.0, None, None, None, None)
                                 for i in range(30)])
            t += 30
            await asyncio.sleep(0.02)
        while not ingest._estimating.done():     # a round has just ended: the one the next batch starts rests
            await asyncio.sleep(0.01)
        # enough new fixes that the device is due whatever its last estimate used (RENEW x at most 2000)
        await ingest.submit([("walker", t + i, 50.0, 8.0, 5.0, None, None, None, None) for i in range(500)])
        started = time.monotonic()
        await ingest.close()
        return started

    try:
        close_called = asyncio.run(feed())
    finally:
        store.close()
    gaps = np.diff(rounds)
    assert len(rounds) >= 2 and (gaps >= 0.2 / ESTIMATOR_SHARE - 0.02).all(), gaps
    assert len(rounds) <= 4                       # not back to back (~12 rounds of 0.2 s in 2.5 s)
    # the round at closing starts at once, not after its rest (0.2 / ESTIMATOR_SHARE - 0.2 = 0.6 s): timed
    # from the call to its start, which a busy machine delays less than the whole close (the round's work)
    assert len(closing_round) == 1 and closing_round[0] - close_called < 0.4, (closing_round, close_called)


def test_noise_rounds_wait_for_enough_devices_or_for_the_first_to_have_waited(tmp_path, monkeypatch):
    """Devices that fall due one at a time are estimated together: a round starts once ROUND_MIN are due,
    or once the first of fewer has waited checkpoint_s (a round's fixed cost is paid once for many)."""
    import asyncio

    from mptrack.serve import _ingest
    from mptrack.serve._ingest import Ingest
    from mptrack.tracking import LiveTracks

    monkeypatch.setattr(_ingest, "ROUND_MIN", 8)
    store = open_store(f"sqlite:///{tmp_path / 'rounds.db'}")
    ingest = Ingest(store, LiveTracks(), calibrate_after=30, checkpoint_s=0.5)
    submit, sizes = ingest._estimator.submit, []

    def recorded(fn, due):                        # the rounds as they start
        sizes.append(len(due))
        return submit(fn, due)

    ingest._estimator.submit = recorded

    def fixes(device: int, t: float, n: int = 30) -> list[tuple]:
        return [(f"d{device}", t + i, 50.0 + 1e-5 * i + 1e-3 * device, 8.0, 5.0, None, None, None, None)
                for i in range(n)]

    async def feed():
        ingest.start()
        seen = []
        for d in range(8):                        # each batch makes one more device due
            await ingest.submit(fixes(d, 1.77e9))
            seen.append(len(sizes))
        while not ingest._estimating.done():
            await asyncio.sleep(0.01)
        for d in (8, 9):
            await ingest.submit(fixes(d, 1.77e9))
        seen.append(len(sizes))
        await asyncio.sleep(0.6)
        await ingest.submit(fixes(0, 1.77e9 + 100, 1))   # any batch after the wait starts the round
        seen.append(len(sizes))
        await ingest.close()
        return seen

    try:
        seen = asyncio.run(feed())
    finally:
        store.close()
    assert (seen, sizes) == ([0] * 7 + [1, 1, 2], [8, 2])


def test_requests_that_arrive_over_a_few_turns_of_the_event_loop_commit_as_one_batch(tmp_path):
    """Requests read while a batch gathers join it (at most GATHER_TURNS turns, while each brings more):
    64 requests arriving over 4 turns of the loop are one commit, not four; a lone request still commits."""
    import asyncio

    from mptrack.serve._ingest import GATHER_TURNS, Ingest
    from mptrack.tracking import LiveTracks

    assert GATHER_TURNS >= 4
    store = open_store(f"sqlite:///{tmp_path / 'gather.db'}")
    ingest = Ingest(store, LiveTracks())

    async def request(k: int, turns: int):
        for _ in range(turns):
            await asyncio.sleep(0)
        await ingest.submit([(f"d{k}", 1.77e9 + k, 50.0 + 1e-4 * k, 8.0, 5.0, None, None, None, None)])

    async def feed():
        ingest.start()
        await asyncio.gather(*(request(k, k % 4) for k in range(64)))
        after_burst = ingest.metrics.totals()["batches"]
        await request(64, 0)
        await ingest.close()
        return after_burst, ingest.metrics.totals()["batches"]

    try:
        burst, total = asyncio.run(feed())
    finally:
        store.close()
    assert (burst, total) == (1, 2)
