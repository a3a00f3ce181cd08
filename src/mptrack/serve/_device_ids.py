"""The ids of the devices a server knows and their integer keys, in a few flat arrays.

A key is a device's row in the live filter and the ``dev`` of its stored fixes.  In a dict and a list
the ids of 10^6 devices took ~135 bytes a device (the string, an int, a dict slot, a list slot), and,
made among a bulk upload's short-lived rows, they kept the interpreter's heap pages from ever emptying.
Here: the ids' UTF-8 bytes one after the other in a buffer, each key's place and length in it, and a
hash table of keys (open addressing, linear probing, FNV-1a over the bytes, at most half full) --
~20 bytes a device beside its id's own bytes.  A batch's ids are looked up in one compiled call; the
ids looked up lately are in a small dict in front (:data:`RECENT`), which answers ~10x faster: a fleet's
active devices are there.  A key never changes for an id (none is ever removed), so it never goes stale.

One writer adds (the ingest's lock held); readers do not lock: the compiled calls hold the interpreter
lock, a key's bytes are written before it enters the table, and a grown set of arrays replaces the old
one as one tuple.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.memory import grown, values_at

__all__ = ["DeviceIds"]

_JIT = dict(cache=True, error_model="numpy")   # not nogil: a lookup must not interleave with an insert
_ENCODING = ("utf-8", "surrogatepass")          # every str has bytes and is read back as it was
_FNV_OFFSET = np.uint64(14695981039346656037)
_FNV_PRIME = np.uint64(1099511628211)
#: How many recently looked-up ids the dict in front holds (~130 bytes each); emptied when full.
RECENT = 65536


@nb.njit(**_JIT)
def _slot(buf, start, n, mask):
    h = _FNV_OFFSET
    for i in range(start, start + n):
        h = (h ^ np.uint64(buf[i])) * _FNV_PRIME
    return np.int64(h & np.uint64(mask))


@nb.njit(**_JIT)
def _find(table, buf, start, length, q, qs, qn):
    """The key of the id ``q[qs:qs + qn]``, or -1."""
    mask = len(table) - 1
    s = _slot(q, qs, qn, mask)
    while True:
        k = table[s]
        if k < 0:
            return -1
        if length[k] == qn + 1:
            b = start[k]
            same = True
            for i in range(qn):
                if buf[b + i] != q[qs + i]:
                    same = False
                    break
            if same:
                return k
        s = (s + 1) & mask


@nb.njit(**_JIT)
def _lookup(table, buf, start, length, q, qoff, out):
    for i in range(len(out)):
        out[i] = _find(table, buf, start, length, q, qoff[i], qoff[i + 1] - qoff[i])


@nb.njit(**_JIT)
def _insert(table, buf, start, length, keys):
    """Enter ``keys`` (their bytes in ``buf``, none in the table yet) into the table."""
    mask = len(table) - 1
    for k in keys:
        s = _slot(buf, start[k], length[k] - 1, mask)
        while table[s] >= 0:
            s = (s + 1) & mask
        table[s] = k


def _encoded(devices) -> tuple[np.ndarray, np.ndarray]:
    """The ids' bytes one after the other, and where each starts (one more: the end)."""
    off = np.zeros(len(devices) + 1, np.int64)
    np.cumsum(np.fromiter(map(len, devices), np.int64, len(devices)), out=off[1:])
    data = "".join(devices).encode(*_ENCODING)
    if len(data) != off[-1]:   # not all ASCII: lengths in bytes
        enc = [d.encode(*_ENCODING) for d in devices]
        np.cumsum(np.fromiter(map(len, enc), np.int64, len(enc)), out=off[1:])
        data = b"".join(enc)
    return np.frombuffer(data, np.uint8), off


class DeviceIds:
    """Device id <-> key (see the module doc).  Keys need not be dense: a shared store's keys are given
    out by every process, and this one knows those of the devices it has seen."""

    def __init__(self):
        # (table, buf, start, length): the hash table of keys (-1: empty), the ids' bytes, each key's
        # place in buf and its length + 1 (0: a key not known here, so that room to grow is zeros)
        self._arrays = (np.full(1024, -1, np.int32), np.zeros(4096, np.uint8), np.zeros(1024, np.int64),
                        np.zeros(1024, np.int32))
        self._used = 0     # bytes of buf in use
        self._count = 0    # keys known
        self._size = 0     # the largest key known + 1
        self._recent: dict[str, int] = {}

    def __len__(self) -> int:
        return self._count

    @property
    def size(self) -> int:
        """One more than the largest key known (0: none)."""
        return self._size

    def get(self, device: str) -> int | None:
        """The key of ``device``, or None."""
        k = self._recent.get(device)
        if k is not None:
            return k
        table, buf, start, length = self._arrays
        q = device.encode(*_ENCODING)
        k = _find(table, buf, start, length, q, 0, len(q))
        if k < 0:
            return None
        self._remember([device], [k])
        return k

    def keys_of(self, devices) -> np.ndarray:
        """The keys of ``devices`` (a sequence of ids), -1 where unknown."""
        recent = self._recent
        keys = [recent.get(d, -1) for d in devices]
        if -1 not in keys:
            return np.array(keys, np.int64)
        missed = [i for i, k in enumerate(keys) if k < 0]
        asked = [devices[i] for i in missed]
        table, buf, start, length = self._arrays
        q, off = _encoded(asked)
        found = np.empty(len(asked), np.int64)
        _lookup(table, buf, start, length, q, off, found)
        out = np.array(keys, np.int64)
        out[missed] = found
        known = found >= 0
        if known.any():
            self._remember([d for d, k in zip(asked, known.tolist()) if k], found[known].tolist())
        return out

    def _remember(self, devices: list[str], keys: list[int]) -> None:
        if len(self._recent) + len(devices) > RECENT:
            self._recent = {}   # one assignment: a reader holds the old dict or the new
        self._recent.update(zip(devices[-RECENT:], keys[-RECENT:]))

    def ids_of(self, keys) -> list[str | None]:
        """The ids of ``keys`` (None where not known here)."""
        _, buf, start, length = self._arrays
        n = (values_at(length, keys) - 1).tolist()
        mv = memoryview(buf)
        return [None if m < 0 else str(mv[s:s + m], *_ENCODING) for s, m in zip(values_at(start, keys).tolist(), n)]

    def known(self, keys) -> np.ndarray:
        """Whether each of ``keys`` is known here."""
        return values_at(self._arrays[3], keys) > 0

    def add(self, pairs) -> None:
        """Learn (key, id) pairs (keys already known are left as they are).  The caller is the one writer."""
        pairs = list(pairs)
        if not pairs:
            return
        keys = np.array([k for k, _ in pairs], np.int64)
        devices = [d for _, d in pairs]
        new = ~self.known(keys)
        if not new.all():
            if not new.any():
                return
            devices = [d for d, n in zip(devices, new.tolist()) if n]
            keys = keys[new]
        ordered = np.sort(keys)
        if ordered[0] < 0 or (ordered[1:] == ordered[:-1]).any():
            raise ValueError("device keys: expected distinct non-negative integers")
        q, off = _encoded(devices)
        table, buf, start, length = self._arrays
        if keys.max() >= len(length):
            size = max(int(keys.max()) + 1, 2 * len(length), 1024)
            start, length = grown(start, size), grown(length, size)
        if self._used + len(q) > len(buf):
            buf = grown(buf[:self._used], max(len(q), len(buf)) + len(buf))
        buf[self._used:self._used + len(q)] = q
        start[keys] = self._used + off[:-1]
        length[keys] = np.diff(off) + 1
        self._used += len(q)
        count = self._count + len(keys)
        if 2 * count > len(table):   # at most half full: a miss probes ~2.5 slots
            size = len(table)
            while 2 * count > size:
                size *= 2
            table = np.full(size, -1, np.int32)
            _insert(table, buf, start, length, np.flatnonzero(length))
        else:
            if table is self._arrays[0] and (buf is not self._arrays[1] or start is not self._arrays[2]):
                table = table.copy()   # readers holding the old arrays must not find keys outside them
            _insert(table, buf, start, length, keys)
        self._arrays = (table, buf, start, length)
        self._count = count
        self._size = max(self._size, int(keys.max()) + 1)
