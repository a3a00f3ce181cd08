"""Atomic files: an output is complete on disk or absent.

:func:`atomic_path` yields a temporary file ``.<name>.XXXXXXXX.tmp<suffix>`` beside
the output (``XXXXXXXX``: the 8 random characters of :func:`tempfile.mkstemp`) and renames it over
the output only when the block succeeds; on any failure, Ctrl-C included, it is removed.  An
OSError while writing becomes an :class:`~mptrack.errors.OutputError` naming the output and the
cause.  Only a SIGKILL (or a power cut) can leave such a file; the next run that takes the output's
lock (:func:`mptrack.runs.output_lock`) removes it (:func:`stale_temp_files` matches exactly these names).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import pickle
import re
import tempfile
from pathlib import Path
from typing import Any, Iterator

from ..errors import MptrackError, OutputError

__all__ = ["atomic_path", "write_json", "write_pickle", "read_pickle", "stale_temp_files", "write_error",
           "remove"]

_UMASK = os.umask(0)
os.umask(_UMASK)
#: Error numbers that, without a file name (pyarrow's writers give none), concern the file being written.
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EPERM, errno.EISDIR,
                 errno.EIO}


def write_error(path, exc: OSError) -> OutputError:
    """The OutputError for an OSError met while writing ``path``: the path and the cause, one line."""
    cause = os.strerror(exc.errno) if exc.errno else exc.strerror or str(exc).splitlines()[0]
    return OutputError(f"{path}: cannot write it: {cause}", path=path, errno=exc.errno)


def _temp_name(path: Path) -> tuple[str, str]:
    """The (prefix, suffix) of :func:`atomic_path`'s temporary files for ``path``."""
    return f".{path.name}.", ".tmp" + path.suffix


def stale_temp_files(path: str | os.PathLike) -> list[Path]:
    """The temporary files of :func:`atomic_path` for ``path`` found beside it: exactly
    ``.<name>.XXXXXXXX.tmp<suffix>`` with mkstemp's 8 random characters (a-z, 0-9, _)."""
    path = Path(path)
    prefix, suffix = _temp_name(path)
    pattern = re.compile(re.escape(prefix) + "[a-z0-9_]{8}" + re.escape(suffix) + r"\Z")
    try:
        names = os.listdir(path.parent)
    except (FileNotFoundError, NotADirectoryError):
        return []
    return sorted(path.parent / n for n in names if pattern.match(n))


def remove(path: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        path.unlink()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` only on success.

    An OSError of the block about the temporary file or ``path`` (disk full, read-only directory,
    ``path`` a directory) is raised as an OutputError naming ``path``; the temporary file never
    outlives the block."""
    path = Path(path)
    prefix, suffix = _temp_name(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
    except OSError as exc:
        raise write_error(path, exc) from exc
    os.close(fd)
    tmp = Path(tmp)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the file the usual permissions
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        named = None if exc.filename is None else str(exc.filename)
        if isinstance(exc, MptrackError) or (named not in (str(tmp), str(path))
                                             and (named is not None or exc.errno not in _WRITE_ERRNOS)):
            raise  # about another file (an input that vanished): the caller names it
        raise write_error(path, exc) from exc
    finally:
        remove(tmp)


def write_json(path, data: Any) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n")
    return Path(path)


def write_pickle(path, obj: Any) -> Path:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            pickle.dump(obj, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return Path(path)


def read_pickle(path) -> Any:
    with open(path, "rb") as fh:
        return pickle.load(fh)
