"""Safe writing of outputs: atomic files (complete on disk or absent), an exclusive lock per output
held for a whole run, and the removal of temporary files that a killed run left behind.

Atomic files: :func:`atomic_path` yields a temporary file ``.<name>.XXXXXXXX.tmp<suffix>`` beside
the output (``XXXXXXXX``: the 8 random characters of :func:`tempfile.mkstemp`) and renames it over
the output only when the block succeeds; on any failure, Ctrl-C included, it is removed.  An
OSError while writing becomes an :class:`~mptrack.errors.OutputError` naming the output and the
cause.  Only a SIGKILL (or a power cut) can leave such a file; the next run that takes the output's
lock removes it (:func:`stale_temp_files` matches exactly these names).

Locks: :func:`output_lock` holds an exclusive lock on each output for the duration of a block (a
whole ``mptrack track`` run); a second process asking for the lock of the same output is refused
at once with an OutputError naming the holder's process id and command.  The lock of
``dir/name`` is the file ``dir/.name.lock``.  Locks are reentrant within a process (a writer inside
a run that already holds the lock does not lock again).

Lock protocol (POSIX, :func:`fcntl.flock`, released by the kernel when the holder dies):

1. open (create) the lock file;
2. ``flock(LOCK_EX | LOCK_NB)``; if another process holds it: when the path still names the file we
   opened, read the holder's pid and command from it and refuse; otherwise the holder was just
   releasing it, so start again;
3. holding the flock, check that the path still names the file we locked (``fstat`` of our
   descriptor equals ``stat`` of the path); if not, the previous holder unlinked it after we
   opened it: close and start again;
4. write our pid and command into it.

To release: unlink the path *while still holding the flock*, then close the descriptor (which
drops the flock).  As a holder unlinks before it unlocks and a taker re-checks the path after it
locks, no two processes ever hold flocks on the file that the path names.  A lock file left by a
killed holder carries no flock: the next run takes it over.

Without :mod:`fcntl` (not POSIX) the lock file is created with ``O_CREAT | O_EXCL`` and removed on
release; a run killed without clean-up leaves it behind, and the refusal then says to delete it
when the process named in it is gone.
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

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None

__all__ = ["atomic_path", "write_json", "write_pickle", "read_pickle", "output_lock", "lock_path",
           "stale_temp_files", "write_error"]

_UMASK = os.umask(0)
os.umask(_UMASK)
#: Tries of the lock protocol before giving up (each retry means another process released the lock
#: between two of our steps).
_LOCK_TRIES = 20
#: The outputs whose lock this process holds: lock path -> [descriptor, depth].
_HELD: dict[Path, list] = {}
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


def _remove(path: Path) -> None:
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
        _remove(tmp)


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


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of output ``path``: ``.<name>.lock`` beside it (its directory's links resolved,
    so two spellings of one directory share one lock)."""
    path = Path(path)
    return Path(os.path.realpath(path.parent)) / f".{path.name}.lock"


@contextlib.contextmanager
def output_lock(*paths, note: str = "") -> Iterator[None]:
    """Hold the exclusive lock of every output in ``paths`` (None is skipped) for the block, and
    remove their stale temporary files (:func:`stale_temp_files`) once locked.

    ``note`` (e.g. the command line) is stored with the holder's pid and shown to a process that is
    refused.  Raises OutputError when another process holds a lock, when an output is a directory,
    or when a lock file cannot be created (read-only directory, ...).  Locks are taken in the order
    given and never waited for, so two runs cannot deadlock."""
    wanted = {lock_path(p): Path(p) for p in paths if p is not None}
    with contextlib.ExitStack() as stack:
        for lock, out in wanted.items():
            stack.enter_context(_held(lock, out, note))
        yield


@contextlib.contextmanager
def _held(lock: Path, out: Path, note: str) -> Iterator[None]:
    if lock in _HELD:  # this process holds it already (a writer inside a locked run)
        _HELD[lock][1] += 1
        try:
            yield
        finally:
            _HELD[lock][1] -= 1
        return
    if out.is_dir():
        raise OutputError(f"{out}: is a directory; the output must be a file name", path=out)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise write_error(out, exc) from exc
    fd = _acquire(lock, out, note)
    _HELD[lock] = [fd, 1]
    try:
        for tmp in stale_temp_files(out):
            _remove(tmp)
        yield
    finally:
        del _HELD[lock]
        _release(lock, fd)


def _acquire(lock: Path, out: Path, note: str) -> int:
    """Take the lock file ``lock`` of output ``out`` (the protocol in the module docstring); its
    descriptor."""
    for _ in range(_LOCK_TRIES):
        fd = _open_lock(lock, out)
        if fd is None:
            continue  # (no fcntl) the holder removed it meanwhile
        if fcntl is None:
            break
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(lock)
            same = _names(lock, fd)
            os.close(fd)
            if same:
                raise _locked(out, lock, holder) from None
            continue  # the holder released it meanwhile
        if _names(lock, fd):
            break
        os.close(fd)  # we locked a file its previous holder had unlinked
    else:
        raise OutputError(f"{out}: cannot take its lock {lock}: other runs keep taking and releasing it",
                          path=out)
    with contextlib.suppress(OSError):  # the holder's identity is a courtesy (a full disk cannot hold it)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n{note}\n".encode())
    return fd


def _open_lock(lock: Path, out: Path) -> int | None:
    try:
        if fcntl is not None:
            return os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        return os.open(lock, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        holder = _holder(lock)
        if holder is None:
            return None
        raise _locked(out, lock, holder) from None
    except OSError as exc:
        raise write_error(out, exc) from exc


def _names(lock: Path, fd: int) -> bool:
    """Whether the path ``lock`` names the open file ``fd``."""
    try:
        here, there = os.fstat(fd), os.stat(lock)
    except FileNotFoundError:
        return False
    return (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)


def _holder(lock: Path) -> str | None:
    """'pid N: command' of the lock's holder as it wrote it ('' if not (yet) written); None if the
    lock file is gone."""
    try:
        text = lock.read_text(errors="replace")
    except FileNotFoundError:
        return None
    except OSError:
        return ""
    pid, _, note = text.partition("\n")
    note = note.strip()
    return f"pid {pid.strip()}" + (f": {note}" if note else "") if pid.strip() else ""


def _locked(out: Path, lock: Path, holder: str | None) -> OutputError:
    who = f"another run ({holder})" if holder else "another run"
    hint = "" if fcntl is not None else f"; if that process is gone, delete {lock}"
    return OutputError(f"{out}: {who} is writing it; wait for it to finish or choose another output{hint}",
                       path=out)


def _release(lock: Path, fd: int) -> None:
    try:
        _remove(lock)  # unlink first, while still holding the flock
    finally:
        os.close(fd)
