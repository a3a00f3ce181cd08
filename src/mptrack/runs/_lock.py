"""The output lock: an exclusive lock on each output of a run, held for the whole run.

:func:`output_lock` holds an exclusive lock on each output for the duration of a block (a
whole ``mptrack track`` run), and removes the output's stale temporary files
(:func:`mptrack._core.files.stale_temp_files`) once it holds it; a second process asking for the lock of the same output is refused
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
import os
import time
from pathlib import Path
from typing import Iterator

from .._core.files import remove, stale_temp_files, write_error
from .._core.validation import check_path
from ..errors import OutputError

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None

__all__ = ["output_lock", "lock_path"]

#: Tries of the lock protocol before giving up (each retry means another process released the lock
#: between two of our steps).
_LOCK_TRIES = 20
#: How long a refused process waits for the lock's holder to have written who it is (s).
HOLDER_WAIT_S = 0.5
#: What a refused process is told to do (after "another run (its pid and note) is writing it; ").
_ADVICE = "wait for it to finish or choose another output"
#: The outputs whose lock this process holds: lock path -> [descriptor, depth].
_HELD: dict[Path, list] = {}


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of an output: ``.<name>.lock`` beside it (its directory's links resolved, so two
    spellings of one directory share one lock).

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    pathlib.Path
    """
    path = check_path("path", path)
    return Path(os.path.realpath(path.parent)) / f".{path.name}.lock"


@contextlib.contextmanager
def output_lock(*paths, note: str = "", advice: str = _ADVICE) -> Iterator[None]:
    """Hold the exclusive lock of every output for the block, and remove their stale temporary files
    once locked.

    Locks are taken in the order given and never waited for, so two runs cannot deadlock; they are
    reentrant within a process.

    Parameters
    ----------
    *paths : str or path-like
        The outputs (None is skipped).
    note : str, optional
        Stored with the holder's pid and shown to a process that is refused (e.g. the command line).
    advice : str, optional
        What the refusal tells a second process to do (default: wait for the run to finish or choose
        another output).

    Yields
    ------
    None

    Raises
    ------
    OutputError
        Another process holds a lock (naming its pid and note), an output is a directory, or a lock file
        cannot be created.
    """
    outs = [check_path("paths", p) for p in paths if p is not None]
    wanted = {lock_path(p): p for p in outs}
    with contextlib.ExitStack() as stack:
        for lock, out in wanted.items():
            stack.enter_context(_held(lock, out, note, advice))
        yield


@contextlib.contextmanager
def _held(lock: Path, out: Path, note: str, advice: str) -> Iterator[None]:
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
    try:
        fd = _acquire(lock, out, note)
    except _Busy as busy:
        raise _locked(out, lock, busy.holder, advice) from None
    _HELD[lock] = [fd, 1]
    try:
        for tmp in stale_temp_files(out):
            remove(tmp)
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
            holder = _written_holder(lock)
            same = _names(lock, fd)
            os.close(fd)
            if same:
                raise _Busy(holder)
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
        holder = _written_holder(lock)
        if holder is None:
            return None
        raise _Busy(holder) from None
    except OSError as exc:
        raise write_error(out, exc) from exc


def _names(lock: Path, fd: int) -> bool:
    """Whether the path ``lock`` names the open file ``fd``."""
    try:
        here, there = os.fstat(fd), os.stat(lock)
    except FileNotFoundError:
        return False
    return (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)


def _written_holder(lock: Path) -> str | None:
    """:func:`_holder`, waiting a moment (at most HOLDER_WAIT_S) for a holder that has just taken the lock
    to write who it is (it writes after it locks: a refusal read in between named no one)."""
    until = time.monotonic() + HOLDER_WAIT_S
    while (holder := _holder(lock)) == "" and time.monotonic() < until:
        time.sleep(0.002)
    return holder


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


class _Busy(Exception):
    """Another process holds the lock (``holder``: what :func:`_holder` read of it)."""

    def __init__(self, holder: str | None):
        super().__init__(holder)
        self.holder = holder


def _locked(out: Path, lock: Path, holder: str | None, advice: str) -> OutputError:
    who = f"another run ({holder})" if holder else "another run"
    hint = "" if fcntl is not None else f"; if that process is gone, delete {lock}"
    return OutputError(f"{out}: {who} is writing it; {advice}{hint}", path=out)


def _release(lock: Path, fd: int) -> None:
    try:
        remove(lock)  # unlink first, while still holding the flock
    finally:
        os.close(fd)
