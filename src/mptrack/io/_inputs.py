"""What one input is: a table in memory, one file, a directory of Parquet files (one dataset), or
several files read as one input -- a list of paths, a glob pattern, or a directory of GPX, FIT, TCX,
NMEA, CSV, ... files.  Each of several files is read and interpreted on its own (its own column names
and units), and its tracks are kept apart: their ids are prefixed with the file's name
(``ride-1.gpx/Morning Ride``), so two files that both call their track "1" give two tracks.
"""

from __future__ import annotations

import glob
import os
import re
from pathlib import Path

import pandas as pd

from .._core.data_checks import FRAME_LABEL
from .._core.validation import check_path
from ..errors import DataError, ParameterError
from ._formats import FORMATS, Skipped

__all__ = ["InputFiles", "resolve_input", "input_paths", "input_files", "input_label", "input_name", "file_labels",
           "PARQUET_SUFFIXES"]

PARQUET_SUFFIXES = (".parquet", ".pq")
_GLOB = re.compile(r"[*?[]")


class InputFiles(list):
    """Several files read as one input: a list of their Paths, with ``root``, the directory they were
    found in (None for a list or a glob), and ``left_out``, the records of that directory's files of no
    input format (:class:`mptrack.io._formats.Skipped`, reported by the readers)."""

    def __init__(self, files, left_out=(), root: Path | None = None):
        super().__init__(files)
        self.left_out, self.root = tuple(left_out), root


def input_paths(source) -> list:
    """The paths of a resolved input that an output must not be, nor lie inside.

    Parameters
    ----------
    source : pandas.DataFrame, pathlib.Path or list of Path
        A resolved input (:func:`resolve_input`).

    Returns
    -------
    list of pathlib.Path
        The files and the directory they come from; none for a table in memory.
    """
    if isinstance(source, InputFiles):
        return [*source, *([source.root] if source.root is not None else [])]
    return [] if isinstance(source, pd.DataFrame) else [check_path("source", source)]


def _hidden(path: Path, root: Path) -> bool:
    """A file that tools keep beside data (``.lock``, ``_SUCCESS``, ``.parts/``): not an input."""
    return any(part.startswith((".", "_")) for part in path.relative_to(root).parts)


def _directory(path: Path):
    """A directory: itself when it is a Parquet dataset (no file in it has another input format),
    else its files of an input format, sorted, as :class:`InputFiles` (the others left out)."""
    files = sorted(p for p in path.rglob("*") if p.is_file() and not _hidden(p, path))
    known = [p for p in files if p.suffix.lower() in FORMATS]
    other = [p for p in files if p not in known]
    if other and not known:
        raise DataError(f"no input files in the directory: {_names(other, path)} of no input format "
                        f"({', '.join(sorted(FORMATS))})", file=path)
    if all(p.suffix.lower() in PARQUET_SUFFIXES for p in known):
        return path  # a Parquet dataset, hive-partitioned or not (or empty: the dataset reader says so)
    left_out = []
    if other:
        left_out.append(Skipped("file of no input format", len(other),
                                f"{path}: {_names(other, path)}: not an input format ({', '.join(sorted(FORMATS))}), "
                                "left out"))
    return InputFiles(known, left_out, root=path)


def _names(files: list[Path], root: Path) -> str:
    return ", ".join(str(p.relative_to(root)) for p in files[:5]) + (", ..." if len(files) > 5 else "")


def resolve_input(source, name: str = "source"):
    """An input as the readers take it.

    Parameters
    ----------
    source : pandas.DataFrame, str, path-like, list or tuple
        A DataFrame (kept as is); one path (a file, or a directory that is a Parquet dataset); or several
        files: a list or tuple of paths (one path: that path), a glob pattern (``rides/*.gpx``; one match:
        that file), or a directory holding files of other formats than Parquet.
    name : str, optional
        The argument an error names.

    Returns
    -------
    pandas.DataFrame, pathlib.Path or InputFiles
        Several files as a sorted list of paths (:class:`InputFiles`).

    Raises
    ------
    ParameterError
        A bad argument (the message starts with ``name``).
    DataError
        A glob that matches nothing.
    """
    if isinstance(source, (pd.DataFrame, InputFiles)):
        return source
    if isinstance(source, (list, tuple)):
        if not source:
            raise ParameterError(f"{name}: expected a file path or a list of them, got an empty list")
        paths = [check_path(name, p) for p in source]
        if len(paths) == 1:
            return resolve_input(paths[0], name)
        dirs = [p for p in paths if p.is_dir()]
        if dirs:
            raise ParameterError(f"{name}: {dirs[0]} is a directory; give several files, or one directory")
        if len(set(map(os.path.abspath, paths))) != len(paths):
            raise ParameterError(f"{name}: a file is given twice")
        return InputFiles(paths)
    path = check_path(name, source)
    if not path.exists() and _GLOB.search(str(path)):
        found = sorted(Path(p) for p in glob.glob(str(path), recursive=True) if Path(p).is_file())
        if not found:
            raise DataError("no file matches this pattern", file=path)
        return found[0] if len(found) == 1 else InputFiles(found)
    if path.is_dir():
        return _directory(path)
    return path


def input_files(source) -> list[Path] | None:
    """The files of an input of several files (:func:`resolve_input`), or None for one source."""
    resolved = resolve_input(source)
    return resolved if isinstance(resolved, InputFiles) else None


def input_label(source, name: str = "path"):
    """What errors and summaries name as an input.

    Parameters
    ----------
    source : pandas.DataFrame, pathlib.Path or list of Path
        A resolved input (:func:`resolve_input`).
    name : str, optional
        The argument an error names.

    Returns
    -------
    str or pathlib.Path
        The path, :data:`FRAME_LABEL` for a table in memory, or "N files in DIR" (their common directory).
    """
    if isinstance(source, pd.DataFrame):
        return FRAME_LABEL
    if isinstance(source, (list, tuple)) and len(source) != 1:
        if not source:
            raise ParameterError(f"{name}: expected a file path or a list of them, got an empty list")
        paths = [check_path(name, p) for p in source]
        return f"{len(paths)} files in {_common(paths)}"
    return check_path(name, source[0] if isinstance(source, (list, tuple)) else source)


def input_name(source) -> str:
    """A short name of a resolved input for progress lines and titles.

    Parameters
    ----------
    source : pandas.DataFrame, pathlib.Path or list of Path
        A resolved input (:func:`resolve_input`).

    Returns
    -------
    str
        The file's name, or "N files".
    """
    if isinstance(source, InputFiles):
        return f"{len(source)} files"
    return FRAME_LABEL if isinstance(source, pd.DataFrame) else check_path("source", source).name


def _common(paths: list[Path]) -> Path:
    return Path(os.path.commonpath([os.path.abspath(p.parent) for p in paths]))


def file_labels(files: list[Path]) -> list[str]:
    """The name of each file within the files' common directory (what its tracks' ids start with)."""
    root = _common(files)
    return [Path(os.path.abspath(p)).relative_to(root).as_posix() for p in files]
