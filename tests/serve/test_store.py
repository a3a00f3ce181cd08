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
