"""Running a task over chunks: serially, in local processes (``concurrent.futures``) or on a Dask
cluster (``dask.distributed``), with resumable output (the chunks' part files).

Every chunk is computed by the same function from the same data, so the results do not depend on the
executor; chunks are returned (and concatenated) in index order.  With an output directory every
finished chunk is written atomically by the worker that computed it, and a later call describing the
same run (its manifest) skips it; the result is then read back from those files, so a resumed run
returns exactly what an uninterrupted one does.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
from pathlib import Path
from typing import Any, Callable, Iterable, Literal

import numpy as np
import pandas as pd

from .._core.validation import check_allocation, check_int
from ..errors import DTypeError, ParameterError
from ._chunks import Chunk, make_chunks
from ._parts import PART_FORMATS, check_manifest, chunk_result, part_path, read_part, write_part

__all__ = ["EXECUTORS", "run_chunks", "run_stream"]

Executor = Literal["serial", "processes", "dask"]
EXECUTORS: tuple[str, ...] = ("serial", "processes", "dask")


def _run_one(task: Callable[[Chunk], Any], chunk: Chunk, out_dir: str | None, parts: tuple[str, ...],
             fmt: str = "parquet"):
    """Worker side: compute one chunk; with ``out_dir`` write its parts atomically (the last one
    last, so its presence means the chunk is done) and return their paths."""
    result = task(chunk)
    named = {parts[0]: result} if len(parts) == 1 and not isinstance(result, dict) else result
    if not isinstance(named, dict) or set(named) != set(parts) or not all(
            hasattr(v, "num_rows") or isinstance(v, pd.DataFrame) for v in named.values()):
        raise DTypeError(f"task: expected {'a pandas.DataFrame' if parts == ('chunk',) else 'tables ' + str(parts)}"
                         f" from chunk {chunk.index}, got {type(result).__name__}")
    if out_dir is None:
        return result
    for name in parts:
        write_part(named[name], part_path(out_dir, name, chunk.index, fmt))
    return chunk_result(out_dir, parts, chunk.index, fmt)


def _with_data(chunks: list[Chunk], data) -> list[Chunk]:
    if data is None:
        return chunks
    return [Chunk(c.index, c.start, c.stop, c.seed, data[c.start:c.stop]) for c in chunks]


def run_chunks(task: Callable[[Chunk], pd.DataFrame], n_items: int, *, chunk_size: int,
               seed: int | None = None, data=None, out_dir=None, executor: Executor = "serial",
               max_workers: int | None = None, client=None, manifest: dict | None = None,
               progress: Callable[[int], None] | None = None) -> pd.DataFrame:
    """Run ``task(chunk) -> DataFrame`` on every chunk of ``range(n_items)`` and concatenate in order.

    With ``out_dir`` the result is read back from the files, so a resumed run returns exactly what an
    uninterrupted one does.

    Parameters
    ----------
    task : callable
        Picklable (a module-level function or a dataclass instance).
    n_items : int
    chunk_size : int
        Items per chunk.
    seed : int, optional
        The run's root entropy (see :class:`Chunk`).
    data : array_like, optional
        ``n_items`` leading rows: chunk i gets its slice as ``chunk.data``.
    out_dir : str or path-like, optional
        Finished chunks are written there atomically as Parquet and skipped when the call is repeated.
    executor : {"serial", "processes", "dask"}, optional
        Who runs the chunks: this process, a spawn-context ProcessPoolExecutor, or a Dask cluster
        (``client``, or a LocalCluster started for the call; install ``mptrack[dask]``).
    max_workers : int, optional
        Processes or Dask workers (default: the cores).
    client : dask.distributed.Client, optional
    manifest : dict, optional
        A JSON-able description of the run stored as ``out_dir/manifest.json``; a later call on the same
        directory must describe the same run.
        (extra description; the chunking and seed are added).
    progress : callable, optional
        ``progress(k)`` each time k more chunks are done (skipped ones included).

    Returns
    -------
    pandas.DataFrame

    Examples
    --------
    >>> import pandas as pd
    >>> from mptrack.runs import run_chunks
    >>> def draws(chunk):
    ...     return pd.DataFrame({"item": range(chunk.start, chunk.stop),
    ...                          "u": [g.random() for g in chunk.generators()]})
    >>> a = run_chunks(draws, 10, chunk_size=3, seed=1)
    >>> b = run_chunks(draws, 10, chunk_size=5, seed=1)
    >>> a.equals(b)
    True
    """
    chunks = make_chunks(n_items, chunk_size, seed)
    # the results of all chunks are held before they are concatenated: at least a table (~1 KiB) each
    check_allocation("n_items", n_items, 1024.0 * len(chunks))
    if data is not None and len(data) != n_items:
        raise ParameterError(f"data: expected {n_items} leading rows, got {len(data)}")
    if out_dir is not None:
        manifest = {"n_items": n_items, "chunk_size": chunk_size, "seed": seed,
                    "task": getattr(task, "__qualname__", type(task).__qualname__), **(manifest or {})}
    parts = run_stream(task, _with_data(chunks, data), out_dir=out_dir, executor=executor,
                       max_workers=max_workers, client=client, manifest=manifest, progress=progress)
    frames = [read_part(p).to_pandas() if isinstance(p, str) else p for p in parts]
    return pd.concat(frames, ignore_index=True)


def run_stream(task: Callable[[Chunk], Any], chunks: Iterable[Chunk], *, parts: tuple[str, ...] = ("chunk",),
               out_dir=None, part_format: str = "parquet", executor: Executor = "serial",
               max_workers: int | None = None, client=None, manifest: dict | None = None,
               progress: Callable[[int], None] | None = None, max_pending: int | None = None) -> list:
    """Run a task on chunks as an iterable produces them (so a reader can stream a file larger than
    memory), keeping a bounded number in flight.

    The results do not depend on the executor: every chunk is computed by the same function from the same
    data.

    Parameters
    ----------
    task : callable
        ``task(chunk)`` returns a table (``parts == ("chunk",)``) or a dict of tables named by ``parts``
        (pandas DataFrames or pyarrow Tables); picklable for processes and Dask.
    chunks : iterable of Chunk
    parts : tuple of str, optional
        The names of a chunk's tables.
    out_dir : str or path-like, optional
        Each chunk's tables are written there by the worker, atomically, as ``<part>-NNNNNN.parquet`` (or
        ``.arrow``), and the result is their path(s); a chunk whose parts all exist is skipped (resume).
    part_format : {"parquet", "arrow"}, optional
    executor : {"serial", "processes", "dask"}, optional
        Who runs the chunks: this process, a spawn-context ProcessPoolExecutor, or a Dask cluster
        (``client``, or a LocalCluster started for the call; install ``mptrack[dask]``).
    max_workers : int, optional
        Processes or Dask workers (default: the cores).
    client : dask.distributed.Client, optional
    manifest : dict, optional
        A JSON-able description of the run stored as ``out_dir/manifest.json``; a later call on the same
        directory must describe the same run.
    progress : callable, optional
        ``progress(k)`` each time k more chunks are done (skipped ones included).
    max_pending : int, optional
        Chunks in flight at most (default twice the workers), so memory follows the chunk size.

    Returns
    -------
    list
        Each chunk's result (tables, or their paths with ``out_dir``), in chunk order.

    Raises
    ------
    ParameterError
        Another run's manifest in ``out_dir``, or an invalid argument.
    """
    if executor not in EXECUTORS:
        raise ParameterError(f"executor: expected one of {EXECUTORS}, got {executor!r}")
    if not callable(task):
        raise ParameterError(f"task: expected a callable, got {type(task).__name__}")
    if part_format not in PART_FORMATS:
        raise ParameterError(f"part_format: expected one of {tuple(PART_FORMATS)}, got {part_format!r}")
    if isinstance(chunks, (str, bytes)) or not np.iterable(chunks):
        raise ParameterError(f"chunks: expected an iterable of Chunk, got {type(chunks).__name__}")
    if not isinstance(parts, tuple) or not parts or not all(isinstance(p, str) and p for p in parts):
        raise ParameterError(f"parts: expected a tuple of part names, got {parts!r}")
    if max_workers is not None:
        max_workers = check_int("max_workers", max_workers, minimum=1)
    target = None
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        check_manifest(out_dir, manifest or {})
        target = str(out_dir)
    done: dict[int, Any] = {}

    def finished(c: Chunk):
        if target is None or not part_path(out_dir, parts[-1], c.index, part_format).exists():
            return None
        return chunk_result(out_dir, parts, c.index, part_format)

    def pending_chunks():
        for c in chunks:
            old = finished(c)
            if old is not None:
                done[c.index] = old
                if progress is not None:
                    progress(1)
                continue
            yield c

    todo = pending_chunks()
    if executor == "serial":
        for c in todo:
            done[c.index] = _run_one(task, c, target, parts, part_format)
            if progress is not None:
                progress(1)
    elif executor == "processes":
        _run_processes(task, todo, (target, parts, part_format), max_workers, max_pending, done, progress)
    else:
        _run_dask(task, todo, (target, parts, part_format), max_workers, max_pending, client, done, progress)
    return [done[i] for i in sorted(done)]


def _run_processes(task, todo, where, max_workers, max_pending, done, progress) -> None:
    workers = max_workers or os.cpu_count() or 1
    limit = max_pending or 2 * workers
    ctx = multiprocessing.get_context("spawn")  # fork is unsafe with numba's threads
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                                initializer=_single_threaded) as pool:
        futures: dict = {}
        try:
            for c in todo:
                if len(futures) >= limit:
                    _collect(futures, done, progress, concurrent.futures.FIRST_COMPLETED)
                futures[pool.submit(_run_one, task, c, *where)] = c.index
            _collect(futures, done, progress, concurrent.futures.ALL_COMPLETED)
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise


def _collect(futures: dict, done: dict, progress, when) -> None:
    finished, _ = concurrent.futures.wait(futures, return_when=when)
    for fut in finished:
        done[futures.pop(fut)] = fut.result()
        if progress is not None:
            progress(1)


def _single_threaded() -> None:
    """Worker processes share the machine: one numba thread each. Ctrl-C (SIGINT, sent by a terminal
    to every process of the group) is the parent's to handle: it cancels the chunks not started and
    waits for the running ones, whose parts stay for a resumed run."""
    import signal

    import numba

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    numba.set_num_threads(1)


def _run_dask(task, todo, where, max_workers, max_pending, client, done, progress) -> None:
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ParameterError("executor: 'dask' needs the dask.distributed package "
                             "(pip install 'mptrack[dask]')") from None

    own = client is None
    if own:
        cluster = LocalCluster(n_workers=max_workers or 2, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        limit = max_pending or 2 * max(1, len(client.scheduler_info().get("workers", {})))
        index: dict = {}
        submitted: list = []
        queue = as_completed()
        try:
            for c in todo:
                while queue.count() >= limit:
                    fut = next(queue)
                    done[index.pop(fut.key)] = fut.result()
                    if progress is not None:
                        progress(1)
                fut = client.submit(_run_one, task, c, *where, pure=False)
                index[fut.key] = c.index
                submitted.append(fut)
                queue.add(fut)
            for fut in queue:
                done[index.pop(fut.key)] = fut.result()
                if progress is not None:
                    progress(1)
        except BaseException:
            client.cancel(submitted)
            raise
    finally:
        if own:
            client.close()
            cluster.close()
