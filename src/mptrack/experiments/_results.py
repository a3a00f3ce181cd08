"""The record a paper reproduction returns, its results.json (see RESULTS.md) and its printout."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import __version__
from .._core.files import write_json

__all__ = ["Table", "Reproduction", "differences", "COUNT_KEYS"]

# The comparison counts of a table and of a whole reproduction (results.json "comparison"):
# published cells compared (numbers we compute; not the inputs or labels we repeat), and how many of
# them we reproduce, differ for a documented reason (an erratum key in "explained_by"), or differ
# unexplained.
COUNT_KEYS = ("compared", "matched", "differing_explained", "differing_unexplained")


def _same(ours: Any, paper: Any, rtol: float, atol: float) -> bool:
    if paper is None:
        return True
    if isinstance(ours, (int, float)) and isinstance(paper, (int, float)) and not isinstance(ours, bool):
        if not (math.isfinite(ours) and math.isfinite(paper)):
            return ours == paper
        return abs(ours - paper) <= atol + rtol * abs(paper)
    return ours == paper


@dataclass
class Table:
    """One table: our ``rows`` beside the ``paper``'s (same shape, None where unpublished).

    ``rtol``/``atol`` say how close a number must be to count as reproduced
    (exact by default, for counts such as flops); they are written to JSON so a
    reader knows what "matches" meant.  ``explained`` maps a (row, column) cell
    to the key of the erratum (``Reproduction.errata``, docs/errata.md) that
    explains why it differs from the paper; a differing cell without a key is
    unexplained.

    ``uncounted`` names columns that repeat what the paper printed rather than
    compute it (inputs such as Table VIII's heights and powers, labels such as
    a model's name, formulas copied as text), or a second reading of cells
    already counted elsewhere: they are shown beside the paper's values but are
    neither compared nor counted.
    """

    title: str
    columns: list[str]
    rows: list[list[Any]]
    paper: list[list[Any]] | None = None
    notes: str = ""
    rtol: float = 0.0
    atol: float = 0.0
    explained: dict[tuple[int, int], str] = field(default_factory=dict)
    uncounted: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        unknown = set(self.uncounted) - set(self.columns[1:])
        if unknown:
            raise ValueError(f"table {self.title!r}: uncounted columns {sorted(unknown)} are not data columns")
        for row in self.rows:
            if len(row) != len(self.columns):
                raise ValueError(f"table {self.title!r}: row {row!r} does not have {len(self.columns)} cells")
        if self.paper is not None:
            if len(self.paper) != len(self.rows) or any(len(p) != len(r) for p, r in zip(self.paper, self.rows)):
                raise ValueError(f"table {self.title!r}: paper values must have the shape of rows")

    def counted(self, j: int) -> bool:
        """Whether column ``j`` holds numbers we compute and compare (not the row label, not uncounted)."""
        return j > 0 and self.columns[j] not in self.uncounted

    def mismatches(self) -> list[tuple[int, int]]:
        """(row, column) cells of the counted columns where our number differs from the published one."""
        if self.paper is None:
            return []
        return [(i, j) for i, (r, p) in enumerate(zip(self.rows, self.paper))
                for j, (a, b) in enumerate(zip(r, p)) if self.counted(j) and not _same(a, b, self.rtol, self.atol)]

    def explain(self, cells, key: str) -> None:
        """Mark ``cells`` ((row, column) pairs) as differing because of erratum ``key``."""
        for i, j in cells:
            self.explained[(i, j)] = key

    def explained_by(self) -> list[tuple[int, int, str]]:
        """(row, column, erratum key) for every differing cell with a documented reason."""
        return [(i, j, self.explained[i, j]) for i, j in self.mismatches() if (i, j) in self.explained]

    def comparison(self) -> dict[str, int]:
        """Counts over the published (non-null) cells of the counted columns: see COUNT_KEYS."""
        if self.paper is None:
            return dict.fromkeys(COUNT_KEYS, 0)
        compared = sum(1 for r in self.paper for j, v in enumerate(r) if v is not None and self.counted(j))
        bad = self.mismatches()
        explained = sum(1 for c in bad if c in self.explained)
        return {"compared": compared, "matched": compared - len(bad), "differing_explained": explained,
                "differing_unexplained": len(bad) - explained}

    def to_json(self) -> dict:
        out: dict[str, Any] = {"title": self.title, "columns": self.columns, "rows": _clean(self.rows)}
        if self.paper is not None:
            out["paper"] = _clean(self.paper)
            out["tolerance"] = {"rtol": self.rtol, "atol": self.atol}
            out["mismatches"] = [list(c) for c in self.mismatches()]
            out["explained_by"] = [list(c) for c in self.explained_by()]
            out["comparison"] = self.comparison()
            if self.uncounted:
                out["uncounted"] = list(self.uncounted)
        if self.notes:
            out["notes"] = self.notes
        return out


def _clean(value):
    """Plain JSON numbers: numpy scalars to Python, floats rounded to 12 significant digits."""
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float):
        if not math.isfinite(value):
            return None
        return float(f"{value:.12g}")
    return value


@dataclass
class Reproduction:
    """Everything a reproduction produced; ``write`` stores results.json atomically."""

    key: str
    paper: str
    seed: int | None
    parameters: dict[str, Any]
    tables: dict[str, Table] = field(default_factory=dict)
    figures: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    errata: dict[str, str] = field(default_factory=dict)
    elapsed_s: float = 0.0

    def comparison(self) -> dict[str, int]:
        """COUNT_KEYS summed over the tables."""
        counts = [t.comparison() for t in self.tables.values()]
        return {k: sum(c[k] for c in counts) for k in COUNT_KEYS}

    def _check_errata(self) -> None:
        for label, table in self.tables.items():
            for _, _, key in table.explained_by():
                if key not in self.errata:
                    raise ValueError(f"table {label!r} cites erratum {key!r}, which the reproduction does not list")

    def to_json(self) -> dict:
        self._check_errata()
        out = {
            "key": self.key,
            "paper": self.paper,
            "mptrack_version": __version__,
            "seed": self.seed,
            "parameters": _clean_dict(self.parameters),
            "tables": {k: t.to_json() for k, t in self.tables.items()},
            "figures": dict(self.figures),
            "comparison": self.comparison(),
            "errata": dict(self.errata),
            "elapsed_s": round(self.elapsed_s, 3),
        }
        if self.notes:
            out["notes"] = list(self.notes)
        return out

    def write(self, out_dir: str | Path) -> Path:
        return write_json(Path(out_dir) / "results.json", self.to_json())


def _clean_dict(d: dict) -> dict:
    return {k: (_clean_dict(v) if isinstance(v, dict) else _clean(v)) for k, v in d.items()}


def differences(rep: Reproduction, *, unexplained: bool = False) -> dict[str, list[tuple[int, int]]]:
    """The cells of a reproduction's tables that differ from the paper.

    Parameters
    ----------
    rep : Reproduction
    unexplained : bool, optional
        Only those without an erratum.

    Returns
    -------
    dict
        {table: [(row, column), ...]}.
    """
    out = {}
    for k, t in rep.tables.items():
        cells = [c for c in t.mismatches() if not (unexplained and c in t.explained)]
        if cells:
            out[k] = cells
    return out
