"""Cell geolocation in the request and answer of Google's Geolocation API and Mozilla's location service
(Ichnaea, BeaconDB), which geoclue, Firefox and Traccar's "universal" provider speak.

Request (``POST /v1/geolocate``, JSON; every field optional)::

    {"radioType": "lte", "considerIp": false, "fallbacks": {"lacf": true},
     "cellTowers": [{"radioType": "lte", "mobileCountryCode": 206, "mobileNetworkCode": 4,
                     "locationAreaCode": 7239, "cellId": 103059577, "signalStrength": -96,
                     "timingAdvance": 2, "age": 0}],
     "wifiAccessPoints": [...]}

A cell needs its radio (per cell or the request's ``radioType``; without one any radio of the table
matches), MCC, MNC, LAC/TAC and ``cellId`` (GSM up to 65535; WCDMA and LTE 28 bits, the LTE cell id
being eNB x 256 + local id) or, for NR, ``newRadioCellId`` (36 bits).  A cell without its full identity
(Android's "unavailable", 2147483647, counts as absent) is left out and counted, as Ichnaea does.
``signalStrength`` is dBm (0: unknown), ``timingAdvance`` GSM (0..63) or LTE (0..1282) steps, ``age``
milliseconds.  Wi-Fi access points are accepted and not used (no Wi-Fi table); ``considerIp`` is
accepted (there is no IP database: a request without known cells is not found).  A field of the wrong
type or out of range is refused with 400 naming it.

Answer: ``{"location": {"lat": .., "lng": ..}, "accuracy": ..}``, the accuracy the radius in metres of
the circle holding the true position with probability 68 % (Google's and Android's convention;
Ichnaea's is 95 %), ``"fallback": "lacf"`` added when only the location area was known.  Errors in
Google's format: ``{"error": {"errors": [{"domain", "reason", "message"}], "code", "message"}}`` --
parseError 400, keyInvalid 400 (``--auth``), notFound 404.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import orjson

from ..cellular import CELL_FIELDS, CONFIDENCE, RADIOS, RADIO_CODES, check_cells, locate_cells
from ..errors import MptrackError, RequestError
from ._store import Store

__all__ = ["GeolocateError", "Query", "Answer", "parse_request", "osmand_query", "Geolocator", "answer_body",
           "error_body"]

#: The most cells one request may list.
MAX_CELLS = 64
#: Cells farther than this from the others of their request are left out (moved cells, wrong table rows).
CLUSTER_M = 50_000.0
#: Android's "unavailable" (Integer.MAX_VALUE) in an identity or a timing advance.
UNAVAILABLE = 2147483647
#: Largest identities: cellId by radio (gsm, wcdma, lte, nr, cdma), newRadioCellId.
_MAX_CID = (65535, (1 << 28) - 1, (1 << 28) - 1, (1 << 36) - 1, 65535)
_MAX_NR = (1 << 36) - 1
_LEVEL = (-160.0, -20.0)
_REASON_DOMAIN = {"parseError": "global", "keyInvalid": "usageLimits", "notFound": "geolocation",
                  "payloadTooLarge": "global"}


_M_PER_DEG = 6_371_008.8 * math.pi / 180.0
#: The CELL_FIELDS the table gives (the phone's level and timing advance follow).
_OBSERVED = CELL_FIELDS.index("rss_dbm")


class GeolocateError(RequestError):
    """A geolocate request refused: ``reason`` is Google's (parseError, keyInvalid, notFound)."""

    def __init__(self, message: str, *, reason: str = "parseError", status: int = 400, field: str | None = None):
        super().__init__(message, status=status, code=reason, field=field)


@dataclass
class Query:
    """A parsed request: the cells (radio code or -1, mcc, mnc, area, cell, level dBm or NaN, timing advance or
    NaN, age ms or NaN), in the order given; whether the area fallback is allowed; what was left out."""

    cells: list = field(default_factory=list)
    lacf: bool = True
    incomplete: int = 0
    wifi: int = 0
    timestamp: object = None   # the request's "timestamp" (a device's report of its cells), as sent


@dataclass
class Answer:
    lat: float
    lon: float
    accuracy: float
    var_e: float = math.nan
    cov_en: float = math.nan
    var_n: float = math.nan
    fallback: str | None = None
    known: int = 0
    unknown: int = 0


def _int(value, name: str, lo: int, hi: int) -> int | None:
    """An integer field (None: absent or Android's unavailable)."""
    if type(value) is int and lo <= value <= hi and value != UNAVAILABLE:  # the common case, at once
        return value
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value or \
            (isinstance(value, float) and not value.is_integer()):
        raise GeolocateError(f"expected an integer, got {_shown(value)}", field=name)
    v = int(value)
    if v == UNAVAILABLE:
        return None
    if not lo <= v <= hi:
        raise GeolocateError(f"expected {lo}..{hi}, got {_shown(value)}", field=name)
    return v


def _radio(value, name: str) -> int | None:
    if value is None:
        return None
    code = RADIO_CODES.get(value.lower()) if isinstance(value, str) else None
    if code is None:
        raise GeolocateError(f"expected one of gsm, wcdma, lte, nr, cdma, got {_shown(value)}", field=name)
    return code


def _bool(value, name: str, default: bool) -> bool:
    if value is None:
        return default
    if not isinstance(value, bool):
        raise GeolocateError(f"expected true or false, got {_shown(value)}", field=name)
    return value


def parse_request(body: bytes) -> Query:
    """The :class:`Query` of a geolocate body (see the module doc); GeolocateError (parseError) naming the
    field otherwise.  An empty body is an empty request."""
    if not body.strip():
        return Query()
    try:
        req = orjson.loads(body)
    except orjson.JSONDecodeError as exc:
        raise GeolocateError(f"the body is not JSON ({exc})") from None
    if not isinstance(req, dict):
        raise GeolocateError(f"expected a JSON object, got {type(req).__name__}")
    top = _radio(req.get("radioType"), "radioType")
    _bool(req.get("considerIp"), "considerIp", True)
    fallbacks = req.get("fallbacks")
    if fallbacks is not None and not isinstance(fallbacks, dict):
        raise GeolocateError(f"expected an object, got {_shown(fallbacks)}", field="fallbacks")
    q = Query(lacf=_bool((fallbacks or {}).get("lacf"), "fallbacks.lacf", True), timestamp=req.get("timestamp"))
    wifi = req.get("wifiAccessPoints")
    if wifi is not None:
        if not isinstance(wifi, list) or not all(isinstance(w, dict) for w in wifi):
            raise GeolocateError("expected a list of objects", field="wifiAccessPoints")
        q.wifi = len(wifi)
    towers = req.get("cellTowers")
    if towers is None:
        return q
    if not isinstance(towers, list):
        raise GeolocateError(f"expected a list, got {_shown(towers)}", field="cellTowers")
    if len(towers) > MAX_CELLS:
        raise GeolocateError(f"at most {MAX_CELLS} cells, got {len(towers)}", field="cellTowers")
    for i, t in enumerate(towers):
        name = f"cellTowers[{i}]"
        if not isinstance(t, dict):
            raise GeolocateError(f"expected an object, got {_shown(t)}", field=name)
        radio = _radio(t.get("radioType"), f"{name}.radioType")
        radio = top if radio is None else radio
        cdma = radio == 4
        mcc = _int(t.get("mobileCountryCode"), f"{name}.mobileCountryCode", 0, 999)
        mnc = _int(t.get("mobileNetworkCode"), f"{name}.mobileNetworkCode", 0, 32767 if cdma else 999)
        area = _int(t.get("locationAreaCode"), f"{name}.locationAreaCode", 0, (1 << 24) - 1)
        if radio == 3:
            cell = _int(t.get("newRadioCellId"), f"{name}.newRadioCellId", 0, _MAX_NR)
            if cell is None and t.get("cellId") is not None:
                raise GeolocateError("an NR cell's identity is newRadioCellId (36 bits), not cellId",
                                     field=f"{name}.cellId")
        else:
            hi = _MAX_CID[radio] if radio is not None else (1 << 32) - 1
            cell = _int(t.get("cellId"), f"{name}.cellId", 0, hi)
            if cell is None and radio is None:
                cell = _int(t.get("newRadioCellId"), f"{name}.newRadioCellId", 0, _MAX_NR)
        level = t.get("signalStrength")
        if level is not None:
            if isinstance(level, bool) or not isinstance(level, (int, float)) or level != level:
                raise GeolocateError(f"expected a number (dBm), got {_shown(level)}", field=f"{name}.signalStrength")
            if level == 0:
                level = None
            elif not _LEVEL[0] <= level <= _LEVEL[1]:
                raise GeolocateError(f"expected dBm between {_LEVEL[0]:g} and {_LEVEL[1]:g} (0: unknown), got "
                                     f"{_shown(level)}", field=f"{name}.signalStrength")
        ta_max = RADIOS[radio].ta_max if radio is not None and RADIOS[radio].ta_max else 1282
        ta = _int(t.get("timingAdvance"), f"{name}.timingAdvance", 0, ta_max)
        age = _int(t.get("age"), f"{name}.age", 0, 1 << 62)
        if mcc is None or mnc is None or area is None or cell is None:
            q.incomplete += 1
            continue
        q.cells.append((-1 if radio is None else radio, mcc, mnc, area, cell,
                        math.nan if level is None else float(level), math.nan if ta is None else float(ta),
                        math.nan if age is None else float(age)))
    return q


def osmand_query(cells: list) -> Query:
    """The :class:`Query` of the ``cell=mcc,mnc,lac,cid[,rssi]`` parameters of an OsmAnd report (their radio
    unknown; an rssi that is not a level in dBm counts as none)."""
    q = Query()
    for c in cells:
        mcc = _int(c[0], "cell", 0, 999)
        mnc = _int(c[1], "cell", 0, 999)
        area = _int(c[2], "cell", 0, (1 << 24) - 1)
        cell = _int(c[3], "cell", 0, _MAX_NR)
        level = c[4] if len(c) > 4 and _LEVEL[0] <= c[4] <= _LEVEL[1] else math.nan
        if None in (mcc, mnc, area, cell):
            q.incomplete += 1
        else:
            q.cells.append((-1, mcc, mnc, area, cell, float(level), math.nan, math.nan))
    return q


class Geolocator:
    """Answers queries from the cell table of a store (:func:`._celltable.load_cell_table`), keeping the
    cells it looked up in memory (the table does not change while the server runs)."""

    def __init__(self, store: Store, level: float = CONFIDENCE, cache: int = 200_000):
        self.store = store
        self.level = level
        self._cache: dict = {}
        self._cache_size = cache
        self._lock = threading.Lock()
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="mptrack-geolocate")
        self._waiting: list = []
        self._solving = False
        self.counters = {"requests": 0, "found": 0, "lacf": 0, "not_found": 0, "cells_known": 0,
                         "cells_unknown": 0, "cells_incomplete": 0, "wifi_ignored": 0}

    def _rows(self, keys: list[tuple]) -> dict:
        """{(mcc, mnc, area, cell): that cell's rows of the table, any radio ([] when unknown)}, each row
        (radio, score, its CELL_FIELDS up to the phone's observations); its stored values checked once,
        when read."""
        cache = self._cache
        out, missing = {}, []
        for k in keys:
            v = cache.get(k)
            if v is None:
                missing.append(k)
            else:
                out[k] = v
        if missing:
            found: dict = {k: [] for k in missing}
            stored = self.store.find_cells(missing)
            if stored:
                areas = self._areas({(r[0], r[1], r[2], r[3]) for r in stored})
                values = []
                for r in stored:
                    fits, offset = areas[(r[0], r[1], r[2], r[3])]
                    values.append((r[5], r[6], r[0], r[11], r[12], _nan(r[13]), fits, _nan(offset), _nan(r[7]),
                                   _nan(r[9]), _nan(r[10]), math.nan, math.nan))
                for r, v in zip(stored, _checked(values)):
                    if v is not None:
                        found[(r[1], r[2], r[3], r[4])].append((r[0], r[14], v))
            out.update(found)
            with self._lock:
                if len(cache) + len(found) > self._cache_size:
                    cache.clear()
                cache.update(found)
        return out

    def locate(self, query: Query) -> Answer:
        """The position of ``query``; GeolocateError notFound when nothing of it is known."""
        known = self._prepare(query)
        if isinstance(known, Answer):
            return known
        return _answer(locate_cells(known.table, level=self.level)[0], known)

    async def answer(self, query: Query) -> Answer:
        """:meth:`locate` in an event loop: the posteriors of concurrent requests are computed together, on
        the geolocator's thread (the compiled kernel releases the interpreter lock, so the loop goes on
        answering meanwhile), while the next requests gather."""
        known = self._prepare(query)
        if isinstance(known, Answer):
            return known
        fut = asyncio.get_running_loop().create_future()
        self._waiting.append((known, fut))
        if not self._solving:
            self._solve_waiting()
        return await fut

    def close(self) -> None:
        self._thread.shutdown(wait=True)

    def _prepare(self, query: Query):
        """The :class:`_Known` cells of ``query`` for the posterior, or the Answer without one (the area
        fallback); GeolocateError notFound when nothing of it is known."""
        c = self.counters
        c["requests"] += 1
        c["cells_incomplete"] += query.incomplete
        c["wifi_ignored"] += query.wifi
        cells = query.cells
        rows = self._rows([x[1:5] for x in cells]) if cells else {}
        table = []
        for x in cells:
            row = _pick(rows[x[1:5]], x[0])
            if row is not None:
                table.append(row + (x[5], x[6]))
        known = len(table)
        c["cells_known"] += known
        c["cells_unknown"] += len(cells) - known
        if known:
            c["found"] += 1
            return _Known(np.array(_cluster(table)), known, len(cells) - known)
        if query.lacf and cells:
            areas = self.store.find_cell_areas(sorted({(x[0], x[1], x[2], x[3]) for x in cells if x[0] >= 0} |
                                                      {(r, x[1], x[2], x[3]) for x in cells if x[0] < 0
                                                       for r in range(len(RADIOS))}))
            if areas:
                best = min(areas, key=lambda a: a[6])  # the smallest area (Ichnaea: pick_best_area)
                c["lacf"] += 1
                return Answer(best[4], best[5], math.sqrt(self.level) * best[6], fallback="lacf",
                              unknown=len(cells))
        c["not_found"] += 1
        raise GeolocateError("Not found", reason="notFound", status=404)

    def _solve_waiting(self) -> None:
        batch, self._waiting = self._waiting, []
        tables = [k.table for k, _ in batch]
        offsets = np.cumsum([0] + [len(t) for t in tables])
        try:
            job = asyncio.get_running_loop().run_in_executor(self._thread, partial(
                locate_cells, np.concatenate(tables), offsets, level=self.level))
        except RuntimeError as exc:  # closed: the requests fail, later ones are not left waiting
            for _, fut in batch:
                if not fut.done():
                    fut.set_exception(exc)
            return
        self._solving = True
        job.add_done_callback(lambda done: self._solved(batch, done))

    def _solved(self, batch: list, done) -> None:
        self._solving = False
        exc = done.exception()
        fixes = done.result() if exc is None else None
        for i, (known, fut) in enumerate(batch):
            if not fut.done():
                if exc is not None:
                    fut.set_exception(exc)
                else:
                    fut.set_result(_answer(fixes[i], known))
        if self._waiting:
            self._solve_waiting()

    def _areas(self, keys: set) -> dict:
        """(fits, mean fit offset) of the areas ``keys`` (cached with the cells)."""
        cache = self._cache
        missing = [k for k in keys if ("area",) + k not in cache]
        if missing:
            got = {("area",) + k: (0, None) for k in missing}
            for a in self.store.find_cell_areas(missing):
                got[("area",) + tuple(a[:4])] = (a[8], a[9])
            with self._lock:
                cache.update(got)
        return {k: cache.get(("area",) + k, (0, None)) for k in keys}


def _checked(values: list[tuple]) -> list:
    """The rows ``values`` (CELL_FIELDS) checked (check_cells), without their observations; None for a row
    out of the ranges locate_cells takes (a cell within 5 degrees of a pole, a range beyond 10,000 km: not
    used)."""
    try:
        return [tuple(v) for v in check_cells(np.array(values))[:, :_OBSERVED].tolist()]
    except MptrackError:
        if len(values) == 1:
            return [None]
        return [v for row in values for v in _checked([row])]


@dataclass
class _Known:
    """The cells of a request the table knows (CELL_FIELDS rows, of one cluster), and how many were known
    and unknown."""
    table: np.ndarray
    known: int
    unknown: int


def _answer(fix: np.ndarray, known: _Known) -> Answer:
    """The Answer of a row of locate_cells."""
    return Answer(*fix[:6].tolist(), known=known.known, unknown=known.unknown)


def _nan(v) -> float:
    return math.nan if v is None else float(v)


def _pick(rows: list, radio: int):
    """The CELL_FIELDS up to the observations of a cell: its row of the request's radio (none: not known);
    without a radio, the best scored."""
    if not rows:
        return None
    if radio >= 0:
        for r in rows:
            if r[0] == radio:
                return r[2]
        return None
    return max(rows, key=lambda r: r[1])[2]


def _cluster(rows: list[tuple]) -> list[tuple]:
    """The rows (CELL_FIELDS) of the largest group of cells whose members lie within CLUSTER_M of another
    member (ties: the first).  Plain Python: a request holds a few cells."""
    n = len(rows)
    if n == 1:
        return rows
    k = math.cos(math.radians(sum(r[0] for r in rows) / n)) * _M_PER_DEG
    xy = [(r[1] * k, r[0] * _M_PER_DEG) for r in rows]
    xs, ys = [p[0] for p in xy], [p[1] for p in xy]
    if math.hypot(max(xs) - min(xs), max(ys) - min(ys)) <= CLUSTER_M:
        return rows  # no two farther apart than their box's diagonal: one group
    group = [-1] * n
    g = 0
    for i in range(n):
        if group[i] >= 0:
            continue
        stack = [i]
        group[i] = g
        while stack:
            x, y = xy[stack.pop()]
            for j in range(n):
                if group[j] < 0 and math.hypot(xy[j][0] - x, xy[j][1] - y) <= CLUSTER_M:
                    group[j] = g
                    stack.append(j)
        g += 1
    sizes = [group.count(h) for h in range(g)]
    best = sizes.index(max(sizes))
    return [rows[i] for i in range(n) if group[i] == best]


def answer_body(a: Answer) -> bytes:
    out = {"location": {"lat": round(a.lat, 7), "lng": round(a.lon, 7)}, "accuracy": round(a.accuracy, 1)}
    if a.fallback:
        out["fallback"] = a.fallback
    return orjson.dumps(out)


def error_body(exc: RequestError) -> bytes:
    """Google's error body of ``exc`` (its code is the reason; a RequestError of the server's other codes is a
    parseError, or keyInvalid for 401/403)."""
    reason = exc.code if exc.code in _REASON_DOMAIN else ("keyInvalid" if exc.status in (401, 403) else
                                                          "payloadTooLarge" if exc.status == 413 else "parseError")
    message = str(exc)
    return json.dumps({"error": {"errors": [{"domain": _REASON_DOMAIN[reason], "reason": reason,
                                             "message": message}], "code": exc.status, "message": message}}).encode()


def _shown(value) -> str:
    text = json.dumps(value) if isinstance(value, (str, int, float, bool, type(None))) else type(value).__name__
    return text if len(text) <= 40 else text[:37] + "..."
