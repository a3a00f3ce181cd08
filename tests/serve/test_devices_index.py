"""The server's compact device bookkeeping against the dict and list it replaced: DeviceIds (id <-> key)
and KeyQueue (an ordered set of keys), driven through random sequences of operations."""

import numpy as np
from hypothesis import given, settings, strategies as st

from mptrack.serve._device_ids import DeviceIds
from mptrack.serve._key_queue import KeyQueue

IDS = st.text(st.characters(codec="utf-8"), min_size=0, max_size=12) | st.sampled_from(["a", "b", "ab", "m1", "m10"])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(st.tuples(st.integers(0, 3000), IDS), max_size=40), max_size=12), st.lists(IDS, max_size=20))
def test_device_ids_answer_as_a_dict_and_a_list(batches, probes):
    index, by_id, by_key = DeviceIds(), {}, {}
    for batch in batches:
        pairs = [(k, d) for k, d in dict(batch).items() if k not in by_key and d not in by_id]
        pairs = list({d: (k, d) for k, d in pairs}.values())   # distinct ids too, as a store gives them
        index.add(pairs + [(k, "ignored: known") for k in list(by_key)[:3]])   # known keys are left as they are
        for k, d in pairs:
            by_id[d], by_key[k] = k, d
        assert len(index) == len(by_id)
        assert index.size == (max(by_key) + 1 if by_key else 0)
    asked = probes + list(by_id)
    assert index.keys_of(asked).tolist() == [by_id.get(d, -1) for d in asked]
    assert [index.get(d) for d in asked] == [by_id.get(d) for d in asked]
    keys = list(range(-2, index.size + 3))
    assert index.ids_of(keys) == [by_key.get(k) for k in keys]
    assert index.known(keys).tolist() == [k in by_key for k in keys]


def test_device_ids_keep_readers_of_old_arrays_consistent():
    """A lookup that took the arrays before a growth never finds a key outside them."""
    from mptrack.serve._device_ids import _find

    index = DeviceIds()
    index.add([(0, "first")])
    for grown in (lambda k: f"{k:040d}", lambda k: f"d{k}"):   # the bytes outgrow their buffer; the keys their table
        before = index._arrays
        index.add([(k, grown(k)) for k in range(index.size, index.size + 400)])
        table, buf, start, length = before
        held = table[table >= 0]   # every key the old table holds has its place and bytes in the old arrays
        assert held.max() < len(start) and (start[held] + length[held] <= len(buf)).all()
        last = grown(index.size - 1).encode()
        assert _find(table, buf, start, length, np.frombuffer(last, np.uint8), 0, len(last)) == -1
        assert index.get(last.decode()) == index.size - 1 and index.get("first") == 0


def test_device_ids_refuse_negative_or_repeated_keys():
    index = DeviceIds()
    for pairs in ([(-1, "a")], [(3, "a"), (3, "b")]):
        try:
            index.add(pairs)
        except ValueError as exc:
            assert "distinct non-negative" in str(exc)
        else:
            raise AssertionError(f"{pairs} accepted")


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["add", "discard", "oldest"]),
                          st.lists(st.integers(0, 3000), max_size=600, unique=True)), max_size=40))
def test_key_queue_behaves_as_an_ordered_set(ops):
    queue, model = KeyQueue(), {}
    for op, keys in ops:
        if op == "add":
            new = queue.add(np.array(keys, np.int64))
            expected = [k for k in keys if k not in model]
            assert new.tolist() == expected
            model.update(dict.fromkeys(expected))
        elif op == "discard":
            queue.discard(keys)
            for k in keys:
                model.pop(k, None)
        else:
            n = len(keys)
            assert queue.oldest(n).tolist() == list(model)[:n]
        assert len(queue) == len(model)
        probe = np.array(keys + [0, 5000], np.int64)
        assert queue.has(probe).tolist() == [k in model for k in probe.tolist()]
    assert queue.oldest(len(queue)).tolist() == list(model)


def test_device_ids_recently_looked_up_stay_bounded_and_right(monkeypatch):
    from mptrack.serve import _device_ids

    monkeypatch.setattr(_device_ids, "RECENT", 4)
    index = DeviceIds()
    index.add([(k, f"d{k}") for k in range(10)])
    for _ in range(3):
        assert index.keys_of([f"d{k}" for k in range(10)] + ["x"]).tolist() == list(range(10)) + [-1]
        assert [index.get(f"d{k}") for k in (9, 3, 3, 0)] == [9, 3, 3, 0] and index.get("x") is None
        assert len(index._recent) <= 4
