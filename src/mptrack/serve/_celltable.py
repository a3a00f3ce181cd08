"""The cell table of cell geolocation: an OpenCelliD / MLS CSV (gzip or plain, any size) read once into
the server's database, with what :func:`mptrack.cellular.locate_cells` needs of each cell computed on
the way (its prior path-loss model, its fit from ``averageSignal``/``range``, Ichnaea's station score),
and one row per location area (its centre and radius for the area fallback, the mean fit of its cells).

The file is streamed in chunks (memory stays flat whatever its size) and every row is stored in one
transaction, so a server never answers from half a table.  What was loaded (the file's path, size and
modification time, and the version of the model) is recorded: ``mptrack serve --cells FILE`` reloads
only when the file changed.  A cell listed twice (same radio, MCC, MNC, area, cell) is stored once (the
first) and counted; rows that cannot be read are skipped and counted by reason (the first of each
kind is kept as an example), never silently.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..cellular import RADIO_CODES, signal_fit, signal_prior, station_score
from ..errors import DataError, ParameterError
from ..io import CELLS, ReadReport, read_chunks
from ._store import Store

__all__ = ["load_cell_table", "table_stamp", "CellTableReport", "MODEL_VERSION"]

#: Bumped when what is computed per cell changes: a table loaded by another version is loaded again.
MODEL_VERSION = 1
EARTH_M = 6_371_008.8
_CHUNK = 200_000


@dataclass
class CellTableReport:
    """What loading a cell table did."""

    file: str
    rows_read: int = 0
    cells: int = 0                      # cells stored
    duplicates: int = 0                 # rows of a cell listed before (not stored)
    areas: int = 0
    fitted: int = 0                     # cells whose path loss the table fits (averageSignal and range)
    skipped: dict = field(default_factory=dict)   # rows not stored, by reason
    examples: list = field(default_factory=list)
    seconds: float = 0.0
    loaded: bool = True                 # False: the database held this table already

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def table_stamp(path) -> str:
    """What identifies a loaded table: the file's resolved path, size, modification time and MODEL_VERSION."""
    p = Path(path).resolve()
    st = p.stat()
    return f"{p}|{st.st_size}|{st.st_mtime_ns}|model {MODEL_VERSION}"


def load_cell_table(store: Store, path, *, force: bool = False) -> CellTableReport:
    """Load the cell table at ``path`` into ``store`` unless it holds this very table already (``force``:
    load anyway).  Bad rows are skipped and counted (the report says how many, why, with examples)."""
    p = Path(path)
    if not p.is_file():
        raise ParameterError(f"cells: {p} is not a file")
    stamp = table_stamp(p)
    start = time.monotonic()
    if not force and store.cell_source() == stamp:
        return CellTableReport(file=str(p), loaded=False)
    report = ReadReport()
    out = CellTableReport(file=str(p))
    now = time.time()
    counted: list[int] = []

    def chunks():
        for chunk in read_chunks(p, CELLS, on_error="skip", report=report, chunk_rows=_CHUNK):
            yield _cell_rows(chunk, now, out)

    def areas(aggregates):
        if not aggregates:  # raised inside the transaction: the table loaded before stays
            examples = (list(report.examples) + out.examples)[:3]
            raise DataError("no cell of the table could be read (" + "; ".join(examples) + ")", file=str(p))
        rows = _area_rows(aggregates)
        counted.append(len(rows))
        return rows

    stored = store.load_cells(chunks(), areas, stamp)
    out.rows_read = report.rows_read
    out.cells = stored
    out.duplicates = report.rows_read - report.rows_skipped - sum(out.skipped.values()) - stored
    for reason, count in report.reasons.items():
        out.skipped[reason] = out.skipped.get(reason, 0) + count
    out.examples = (list(report.examples) + out.examples)[:10]
    out.areas = counted[0] if counted else 0
    out.seconds = time.monotonic() - start
    return out


def _cell_rows(chunk, now: float, out: CellTableReport) -> list[tuple]:
    """The stored rows (CELL_COLUMNS of the store) of one validated chunk."""
    n = len(chunk)
    if n == 0:
        return []
    radio_text = chunk["radio"].astype(str).str.strip()
    exact = radio_text.map(RADIO_CODES)  # the table's own spelling, else its lower case (a dict lookup per row)
    radio = exact.fillna(radio_text.str.lower().map(RADIO_CODES)).fillna(-1).to_numpy(np.int64)
    bad = radio < 0
    if bad.any():
        out.skipped["radio: not one of GSM, UMTS, LTE, NR, CDMA"] = out.skipped.get(
            "radio: not one of GSM, UMTS, LTE, NR, CDMA", 0) + int(bad.sum())
        if len(out.examples) < 10:
            first = int(np.flatnonzero(bad)[0])
            out.examples.append(f"row {int(chunk['row'].iloc[first])}: radio {radio_text.iloc[first]!r} is not one of "
                                "GSM, UMTS, LTE, NR, CDMA")
        chunk, radio = chunk.loc[~bad], radio[~bad]
        n = len(chunk)
        if n == 0:
            return []

    def col(name):
        return chunk[name].to_numpy(float) if name in chunk.columns else np.full(n, np.nan)

    a0, n0 = signal_prior(radio, col("height_m"))
    rng, avg, samples = col("range"), col("averageSignal"), col("samples")
    fit = signal_fit(a0, n0, rng, avg, samples)
    score = station_score(samples, col("created"), col("updated"), now)
    lat, lon = col("lat"), col("lon")
    mcc, net, area, cell = (chunk[c].to_numpy(np.int64) for c in ("mcc", "net", "area", "cell"))
    out.fitted += int(np.isfinite(fit).sum())
    cols = [radio, mcc, net, area, cell, lat, lon, rng, samples, col("changeable"), col("azimuth_deg"), a0, n0, fit,
            score, col("unit"), col("earfcn")]
    order = np.lexsort((radio, cell, area, net, mcc))  # in key order: the index is written in sequence (stable:
    cols = [c[order] for c in cols]                     # of a cell listed twice, the first stays first)
    # NULL for a missing value (NaN), integers as integers (unit and earfcn too: INTEGER columns in every
    # store); only float columns can hold a NaN
    lists = [c.tolist() if c.dtype.kind != "f" or np.isfinite(c).all() else
             [None if v != v else v for v in c.tolist()] for c in cols[:15]]
    lists += [[None if v != v else int(v) for v in c.tolist()] for c in cols[15:]]
    return list(zip(*lists))


def _area_rows(aggregates) -> list[tuple]:
    """The stored area rows (AREA_COLUMNS) from the stored cells' aggregates (AREA_AGGREGATES): centre, radius
    (half the diagonal of the cells' bounding box, at least 1 km), cells, fits and their mean offset."""
    rows = []
    for radio, mcc, net, area, n, lat, lon, la0, la1, lo0, lo1, nfit, offset in aggregates:
        dy = (la1 - la0) * math.pi / 180.0 * EARTH_M
        dx = (lo1 - lo0) * math.pi / 180.0 * EARTH_M * math.cos(math.radians(lat))
        radius = max(0.5 * math.hypot(dx, dy), 1000.0)
        rows.append((radio, mcc, net, area, lat, lon, radius, int(n), int(nfit), offset if nfit else None))
    return rows
