"""The part files of a chunked run: their names, writing (atomic) and reading back, and the run's
manifest (what a resumed run must share with the interrupted one)."""

from __future__ import annotations

import json
from pathlib import Path

from .._core.files import atomic_path, write_json
from .._core.validation import check_int, check_path, lookup
from ..errors import DataError, ParameterError

__all__ = ["PART_FORMATS", "part_path", "read_part", "write_part", "chunk_result", "check_manifest"]


#: File formats of a run's parts: Parquet (compact) or Arrow IPC (uncompressed, memory-mapped on reading:
#: the fastest to write and read back for a run that is about to rewrite them into its output).
PART_FORMATS = {"parquet": ".parquet", "arrow": ".arrow"}


def part_path(out_dir: Path, name: str, index: int, fmt: str = "parquet") -> Path:
    """The file of one part of a chunk in a run directory: ``<name>-NNNNNN<suffix>``.

    Parameters
    ----------
    out_dir : str or path-like
    name : str
        The part's name (no "/").
    index : int
        The chunk's index, >= 0.
    fmt : {"parquet", "arrow"}, optional

    Returns
    -------
    pathlib.Path
    """
    out_dir = check_path("out_dir", out_dir)
    if not isinstance(name, str) or not name or "/" in name:
        raise ParameterError(f"name: expected a part name (a non-empty str without '/'), got {name!r}")
    index = check_int("index", index, minimum=0)
    suffix = lookup("fmt", fmt, PART_FORMATS, what="part format")
    return out_dir / f"{name}-{index:06d}{suffix}"


def read_part(path):
    """A part written by :func:`run_stream`, as a pyarrow Table (an Arrow IPC part memory-mapped).

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    pyarrow.Table

    Raises
    ------
    DataError
        A file that is missing or not a part (naming it).
    """
    import pyarrow as pa
    import pyarrow.feather as feather
    import pyarrow.parquet as pq

    path = check_path("path", path)
    try:
        return feather.read_table(path, memory_map=True) if path.suffix == ".arrow" else pq.read_table(path)
    except (OSError, ValueError, pa.ArrowException) as exc:   # missing, unreadable or not a part
        raise DataError(f"cannot read the part ({exc})", file=path) from None


def write_part(table, path: Path) -> None:
    """Write a part (a pandas DataFrame or pyarrow Table) atomically: Arrow IPC for ``.arrow``, else
    Parquet."""
    import pyarrow as pa
    import pyarrow.feather as feather

    with atomic_path(path) as tmp:
        if path.suffix == ".arrow":
            table = table if isinstance(table, pa.Table) else pa.Table.from_pandas(table, preserve_index=False)
            feather.write_feather(table, tmp, compression="uncompressed")
        else:
            table.to_parquet(tmp, engine="pyarrow", index=False)


def chunk_result(out_dir, parts: tuple[str, ...], index: int, fmt: str):
    """What a chunk written to ``out_dir`` gives back: the path of its one part, or its paths by part name."""
    paths = {name: str(part_path(out_dir, name, index, fmt)) for name in parts}
    return paths if len(parts) > 1 else paths[parts[0]]


def check_manifest(out_dir: Path, manifest: dict) -> None:
    """Store ``manifest`` as ``out_dir/manifest.json``, or refuse a directory whose manifest describes
    another run (ParameterError)."""
    path = out_dir / "manifest.json"
    if path.exists():
        old = json.loads(path.read_text())
        if old != manifest:
            raise ParameterError(
                f"out_dir: {out_dir} holds chunks of a different study ({old}); "
                f"this one is {manifest}. Use another directory or delete it.")
    else:
        write_json(path, manifest)
