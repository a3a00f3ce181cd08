"""Checks of data arguments: an input file or a DataFrame read like one, the columns of a table, and
outputs that must not overwrite an input (or each other).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import DTypeError, ParameterError, ShapeError
from .validation import as_array, check_path

__all__ = ["FRAME_LABEL", "source_label", "ON_ERROR", "check_on_error", "check_frame", "POINT_TEXT", "point_numbers", "check_outputs"]

#: The name errors give a DataFrame passed instead of a file.
FRAME_LABEL = "<DataFrame>"


def source_label(source):
    """What errors name as the file of ``source`` (a path, or a DataFrame read like a file): its path,
    or FRAME_LABEL for a DataFrame; anything else is a ParameterError naming ``path``."""
    import pandas as pd

    return FRAME_LABEL if isinstance(source, pd.DataFrame) else check_path("path", source)


#: what a reader does with a bad row: raise a DataError naming it, or skip it and count it
ON_ERROR = ("raise", "skip")


def check_on_error(on_error: str) -> str:
    """``on_error`` if it is one of :data:`ON_ERROR`."""
    if on_error not in ON_ERROR:
        raise ParameterError(f"on_error: expected one of {ON_ERROR}, got {on_error!r}")
    return on_error


def check_frame(name: str, value, columns=(), numbers: dict | None = None, *, empty: bool = False):
    """A pandas DataFrame with the ``columns`` and at least one row (any number with ``empty``).
    ``numbers`` maps columns (where present) to the :func:`as_array` options their values must meet
    (``{"t": {}}``: finite numbers; ``{"rss_dbm": dict(allow_nan=True, low=-160, high=0)}``); each is
    checked as the array ``name.column``, so messages start with the argument's name."""
    import pandas as pd

    if not isinstance(value, pd.DataFrame):
        raise ParameterError(f"{name}: expected a pandas DataFrame, got {type(value).__name__}")
    missing = [c for c in columns if c not in value.columns]
    if missing:
        raise ShapeError(f"{name}: expected the column(s) {', '.join(missing)}; it has "
                         f"{', '.join(map(str, value.columns))}")
    if value.empty and not empty:
        raise ShapeError(f"{name}: expected at least one row, got none")
    for col, options in (numbers or {}).items():
        if col in value.columns:
            try:
                data = pd.to_numeric(value[col]).to_numpy(dtype=float, na_value=np.nan)
            except (ValueError, TypeError) as exc:
                raise DTypeError(f"{name}.{col}: expected numbers ({exc})") from None
            as_array(f"{name}.{col}", data, **options)
    return value


#: The text columns of a point table (``mptrack track``'s output); its other columns hold numbers.
POINT_TEXT = ("track_id", "time", "flag", "method", "gap", "is_outlier")


def point_numbers(frame, known=()) -> dict:
    """The :func:`check_frame` ``numbers`` of a point table: t finite, every other column that holds
    numbers (the ``known`` numeric columns, and any column of a numeric dtype) numbers or NaN (what a
    point table leaves out: no NIS at a track's first fix, no velocity, no geographic origin), never
    +-Inf."""
    import pandas as pd

    numeric = [c for c in getattr(frame, "columns", ()) if c not in POINT_TEXT
               and not pd.api.types.is_bool_dtype(frame[c])
               and (c in known or pd.api.types.is_numeric_dtype(frame[c]))]
    return {c: {} if c == "t" else {"allow_nan": True} for c in numeric}


def check_outputs(*inputs, **outputs) -> None:
    """Refuse an output (name=path) that is one of the input files, lies inside an input directory
    (writing it would overwrite the user's data, or add to the dataset), or is the same file as
    another output of the run (the later would overwrite the earlier).

    The same file is found through symbolic links (paths resolved) and, for an output that exists,
    hard links too (:func:`os.path.samefile`).  Inputs that are not paths (None, a table in memory)
    are ignored."""
    sources = [Path(p) for p in inputs if isinstance(p, (str, os.PathLike))]
    named = [(name, Path(path)) for name, path in outputs.items() if path is not None]
    for k, (name, path) in enumerate(named):
        for source in sources:
            if _same_file(path, source):
                raise ParameterError(f"{name}: {path} is an input of this run; writing it would overwrite the input")
            if source.is_dir() and source.resolve() in path.resolve().parents:
                raise ParameterError(f"{name}: {path} is inside the input directory {source}; write it elsewhere "
                                     "(a later read of the directory would take it as input)")
        for other, other_path in named[:k]:
            if _same_file(path, other_path):
                raise ParameterError(f"{name}: {path} is also given as {other}; each output of a run needs a "
                                     "file of its own")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): compare the paths with links resolved
        return a.resolve() == b.resolve()
