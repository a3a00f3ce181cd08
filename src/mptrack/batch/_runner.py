"""Scale-out: split a batch or a Monte-Carlo study into chunks and run them
serially, in local processes (``concurrent.futures``) or on a Dask cluster
(``dask.distributed``), with resumable Parquet output.

Determinism: run ``i`` of a study draws from the stream
``SeedSequence(seed, spawn_key=(i,))`` -- the i-th child that
``SeedSequence(seed).spawn`` would give -- so a run's numbers do not depend on
the chunking, the executor or the order in which chunks finish.  Chunks are
concatenated in index order.

Resumability: with ``out_dir`` every finished chunk is written atomically to
``out_dir/chunk-NNNNNN.parquet`` (by the worker that computed it) and a later
call with the same ``manifest`` skips it; the result is always read back from
those files, so a resumed run returns exactly what an uninterrupted one does.
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import json
import multiprocessing
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Literal

import numpy as np
import pandas as pd

from .._core.files import atomic_path, write_json
from .._core.validation import (
    _to_array,
    check_allocation,
    check_covariance,
    check_int,
    check_path,
    lookup,
)
from ..errors import DataError, DTypeError, ParameterError, ShapeError
from ..models import LinearGaussianModel, require_model
from ..result import BatchFilterResult
from ._filters import _shared, gain_sequence, kalman_filter, steady_state_filter

__all__ = ["Chunk", "Chunks", "make_chunks", "run_chunks", "run_stream", "part_path", "read_part", "MonteCarloTask",
           "monte_carlo", "filter_chunked", "EXECUTORS"]

Executor = Literal["serial", "processes", "dask"]
EXECUTORS: tuple[str, ...] = ("serial", "processes", "dask")


@dataclass(frozen=True, eq=False)
class Chunk:
    """Items ``start .. stop-1`` of a study, handed to a task.

    seed  the study's root entropy (None when the task draws nothing)
    data  the slice ``data[start:stop]`` of the array given to :func:`run_chunks`, or None
    """

    index: int
    start: int
    stop: int
    seed: int | None = None
    data: Any = field(default=None, repr=False)

    @property
    def size(self) -> int:
        return self.stop - self.start

    def seed_sequences(self) -> list[np.random.SeedSequence]:
        """Per-item streams: item i gets ``SeedSequence(seed, spawn_key=(i,))``."""
        if self.seed is None:
            raise ParameterError("seed: this study was started without a seed")
        return [np.random.SeedSequence(self.seed, spawn_key=(i,)) for i in range(self.start, self.stop)]

    def generators(self) -> list[np.random.Generator]:
        return [np.random.default_rng(s) for s in self.seed_sequences()]


class Chunks(Sequence):
    """The chunks of ``range(n_items)``, made on access (a study of 10^12 items costs no memory).

    A read-only sequence: ``len``, indexing (negative too), slicing and iteration, like ``range``."""

    def __init__(self, n_items: int, chunk_size: int, seed: int | None):
        self.n_items, self.chunk_size, self.seed = n_items, chunk_size, seed
        self._range = range(0, n_items, chunk_size)

    def __len__(self) -> int:
        return len(self._range)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        lo = self._range[index]   # IndexError / TypeError as for range
        return Chunk(lo // self.chunk_size, lo, min(lo + self.chunk_size, self.n_items), self.seed)

    def __eq__(self, other) -> bool:
        if isinstance(other, Chunks):
            return (self.n_items, self.chunk_size, self.seed) == (other.n_items, other.chunk_size, other.seed)
        return isinstance(other, (list, tuple)) and len(other) == len(self) and list(self) == list(other)

    def __repr__(self) -> str:
        return f"Chunks(n_items={self.n_items}, chunk_size={self.chunk_size}, seed={self.seed})"


def make_chunks(n_items: int, chunk_size: int, seed: int | None = None) -> Chunks:
    """Split ``range(n_items)`` into consecutive chunks of ``chunk_size`` (the last may be shorter).

    The chunks are made lazily (:class:`Chunks`), so a huge ``n_items`` costs no memory."""
    n_items = check_int("n_items", n_items, minimum=1)
    chunk_size = check_int("chunk_size", chunk_size, minimum=1)
    if seed is not None:
        seed = check_int("seed", seed, minimum=0)
    return Chunks(n_items, chunk_size, seed)


def _digest(*arrays) -> str:
    """A short fingerprint of arrays' contents, to tell one study's chunks from another's."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


#: File formats of a run's parts: Parquet (compact) or Arrow IPC (uncompressed, memory-mapped on reading:
#: the fastest to write and read back for a run that is about to rewrite them into its output).
PART_FORMATS = {"parquet": ".parquet", "arrow": ".arrow"}


def part_path(out_dir: Path, name: str, index: int, fmt: str = "parquet") -> Path:
    """The file of part ``name`` of chunk ``index`` in a run directory."""
    out_dir = check_path("out_dir", out_dir)
    if not isinstance(name, str) or not name or "/" in name:
        raise ParameterError(f"name: expected a part name (a non-empty str without '/'), got {name!r}")
    index = check_int("index", index, minimum=0)
    suffix = lookup("fmt", fmt, PART_FORMATS, what="part format")
    return out_dir / f"{name}-{index:06d}{suffix}"


def read_part(path):
    """A part written by :func:`run_stream`, as a pyarrow Table."""
    import pyarrow.feather as feather
    import pyarrow.parquet as pq

    path = check_path("path", path)
    try:
        return feather.read_table(path, memory_map=True) if path.suffix == ".arrow" else pq.read_table(path)
    except (OSError, ValueError) as exc:          # missing, unreadable or not a part (pyarrow's ArrowInvalid)
        raise DataError(f"cannot read the part ({exc})", file=path) from None


def _write_part(table, path: Path) -> None:
    import pyarrow as pa
    import pyarrow.feather as feather

    with atomic_path(path) as tmp:
        if path.suffix == ".arrow":
            table = table if isinstance(table, pa.Table) else pa.Table.from_pandas(table, preserve_index=False)
            feather.write_feather(table, tmp, compression="uncompressed")
        else:
            table.to_parquet(tmp, engine="pyarrow", index=False)


def _chunk_result(out_dir, parts: tuple[str, ...], index: int, fmt: str):
    """What a chunk written to ``out_dir`` gives back: the path of its one part, or its paths by part name."""
    paths = {name: str(part_path(out_dir, name, index, fmt)) for name in parts}
    return paths if len(parts) > 1 else paths[parts[0]]


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
        _write_part(named[name], part_path(out_dir, name, chunk.index, fmt))
    return _chunk_result(out_dir, parts, chunk.index, fmt)


def _check_manifest(out_dir: Path, manifest: dict) -> None:
    path = out_dir / "manifest.json"
    if path.exists():
        old = json.loads(path.read_text())
        if old != manifest:
            raise ParameterError(
                f"out_dir: {out_dir} holds chunks of a different study ({old}); "
                f"this one is {manifest}. Use another directory or delete it.")
    else:
        write_json(path, manifest)


def _with_data(chunks: list[Chunk], data) -> list[Chunk]:
    if data is None:
        return chunks
    return [Chunk(c.index, c.start, c.stop, c.seed, data[c.start:c.stop]) for c in chunks]


def run_chunks(task: Callable[[Chunk], pd.DataFrame], n_items: int, *, chunk_size: int,
               seed: int | None = None, data=None, out_dir=None, executor: Executor = "serial",
               max_workers: int | None = None, client=None, manifest: dict | None = None,
               progress: Callable[[int], None] | None = None) -> pd.DataFrame:
    """Run ``task(chunk) -> DataFrame`` on every chunk of ``range(n_items)``; concatenate in order.

    task        a picklable callable (a module-level function or a dataclass instance)
    chunk_size  items per chunk; ``seed`` the study's root entropy (see :class:`Chunk`)
    data        optional array with ``n_items`` leading rows: chunk i gets its slice as ``chunk.data``
    out_dir     optional directory: finished chunks are written there atomically as Parquet
                and skipped when the call is repeated (resume after an interruption)
    executor    "serial", "processes" (a spawn-context ProcessPoolExecutor of ``max_workers``)
                or "dask" (``client``, a dask.distributed.Client; without one a LocalCluster
                of ``max_workers`` single-threaded workers is started for the call)
    manifest    extra JSON-able description of the study stored with the chunks; a
                later call on the same ``out_dir`` must describe the same study
    progress    ``progress(k)`` each time k more chunks are done (skipped ones included),
                e.g. the ``advance`` of ``RunContext.progress.task``
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
    """Run ``task`` on chunks as an iterable produces them (so a reader can stream a file larger
    than memory); returns the results in chunk order.

    task      ``task(chunk)`` returns a table (``parts`` = ("chunk",)) or a dict of tables named by
              ``parts`` (pandas DataFrames or pyarrow Tables)
    out_dir   each chunk's tables are written there by the worker, atomically, as
              ``<part>-NNNNNN.parquet`` (or ``.arrow``, ``part_format``), and the result is their
              path (one part) or a dict of paths; a chunk whose parts all exist is skipped (resume),
              the chunk itself never computed
    manifest  a JSON-able description stored as ``out_dir/manifest.json``; a later run on the
              same directory must describe the same run (else ParameterError)
    executor  as for :func:`run_chunks`; at most ``max_pending`` chunks (default twice the
              workers) are in flight, so memory stays bounded by the chunk size
    The results do not depend on the executor: every chunk is computed by the same function
    from the same data.
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
        _check_manifest(out_dir, manifest or {})
        target = str(out_dir)
    done: dict[int, Any] = {}

    def finished(c: Chunk):
        if target is None or not part_path(out_dir, parts[-1], c.index, part_format).exists():
            return None
        return _chunk_result(out_dir, parts, c.index, part_format)

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


@dataclass(frozen=True, eq=False)
class MonteCarloTask:
    """One chunk of a Monte-Carlo study: simulate, filter with the batch engine, score.

    Run i draws, from its own stream, the process noise (steps, p) and then the
    measurement noise (steps, m), exactly as :func:`mptrack.sim.simulate_linear`
    does, from x(0) = 0; the filter starts from x(0/0) = 0 (and P0 for "kalman").
    Returns one row per run: ``run`` and the RMSE over time of each state component.
    """

    model: LinearGaussianModel
    steps: int
    method: Literal["steady-state", "kalman"] = "steady-state"
    P0: np.ndarray | None = None

    def __post_init__(self) -> None:
        require_model(self.model)
        object.__setattr__(self, "steps", check_int("steps", self.steps, minimum=1))
        if self.method not in ("steady-state", "kalman"):
            raise ParameterError(f"method: expected 'steady-state' or 'kalman', got {self.method!r}")
        if self.P0 is not None:
            object.__setattr__(self, "P0", check_covariance("P0", self.P0, self.model.n))

    def __call__(self, chunk: Chunk) -> pd.DataFrame:
        model, T = self.model, self.steps
        if not isinstance(chunk, Chunk):
            raise ParameterError(f"chunk: expected a Chunk (from make_chunks), got {type(chunk).__name__}")
        check_allocation("steps", T, 8.0 * chunk.size * T * (3 * model.n + 2 * model.m))
        Lq = model.noise_factor()
        Lr = np.linalg.cholesky(model.R)
        runs = chunk.size
        w = np.empty((runs, T, Lq.shape[1]))
        v = np.empty((runs, T, model.m))
        for j, rng in enumerate(chunk.generators()):
            w[j] = rng.standard_normal((T, Lq.shape[1]))
            v[j] = rng.standard_normal((T, model.m))
        w = w @ Lq.T
        truth = np.empty((runs, T, model.n))
        x = np.zeros((runs, model.n))
        for k in range(T):
            x = x @ model.F.T + w[:, k]
            truth[:, k] = x
        z = truth @ model.H.T + v @ Lr.T
        if self.method == "kalman":
            est = kalman_filter(model, z, gains=gain_sequence(model, T, self.P0)).x
        else:
            est = steady_state_filter(model, z).x
        rmse = np.sqrt(np.mean((est - truth) ** 2, axis=1))
        cols = {"run": np.arange(chunk.start, chunk.stop)}
        cols.update({f"rmse_x{i}": rmse[:, i] for i in range(model.n)})
        return pd.DataFrame(cols)


def monte_carlo(model: LinearGaussianModel, steps: int, runs: int, *, seed: int,
                method: Literal["steady-state", "kalman"] = "steady-state", P0=None,
                chunk_size: int = 1000, executor: Executor = "serial", out_dir=None,
                max_workers: int | None = None, client=None, progress=None) -> pd.DataFrame:
    """A Monte-Carlo study of ``runs`` simulated tracks of ``steps`` steps, chunked.

    Returns one row per run (``run``, ``rmse_x0`` ..): see :class:`MonteCarloTask`.
    The numbers depend on ``seed`` only (not on chunking or executor).
    """
    if method not in ("steady-state", "kalman"):
        raise ParameterError(f"method: expected 'steady-state' or 'kalman', got {method!r}")
    require_model(model)
    steps = check_int("steps", steps, minimum=1)
    runs = check_int("runs", runs, minimum=1)
    # the result holds one row per run (run + one RMSE per state); a chunk of runs holds z and x
    check_allocation("runs", runs, 8.0 * runs * (model.n + 2))
    chunk_size = check_int("chunk_size", chunk_size, minimum=1)
    check_allocation("steps", steps, 8.0 * min(chunk_size, runs) * steps * (3 * model.n + 2 * model.m))
    task = MonteCarloTask(model, steps, method, P0)
    desc = {"steps": steps, "method": method, "model": _digest(model.F, model.H, model.Q, model.R),
            "P0": None if P0 is None else _digest(task.P0)}
    return run_chunks(task, runs, chunk_size=chunk_size, seed=seed, out_dir=out_dir, executor=executor,
                      max_workers=max_workers, client=client, manifest=desc, progress=progress)


def _filtered(run: Callable[..., BatchFilterResult], model, z, kwargs: dict) -> BatchFilterResult:
    result = run(model, z, **kwargs)
    if not isinstance(result, BatchFilterResult):
        raise DTypeError(f"run: expected a batch filter returning a BatchFilterResult (e.g. "
                         f"mptrack.batch.steady_state_filter), got {type(result).__name__}")
    return result


@dataclass(frozen=True, eq=False)
class _FilterTask:
    run: Callable[..., BatchFilterResult]
    model: LinearGaussianModel
    kwargs: dict

    def __call__(self, chunk: Chunk) -> pd.DataFrame:
        x = _filtered(self.run, self.model, chunk.data, self.kwargs).x
        B, T, n = x.shape
        cols = {"track": np.repeat(np.arange(chunk.start, chunk.stop), T), "t": np.tile(np.arange(T), B)}
        flat = x.reshape(B * T, n)
        cols.update({f"x{i}": flat[:, i] for i in range(n)})
        return pd.DataFrame(cols)


def filter_chunked(run: Callable[..., BatchFilterResult], model: LinearGaussianModel, z, *, chunk_size: int,
                   executor: Executor = "serial", out_dir=None, max_workers: int | None = None,
                   client=None, progress=None, **kwargs) -> BatchFilterResult:
    """Filter a large batch ``z`` (B, T, m) in chunks of tracks with ``run`` (a batch filter).

    Each chunk's states go to a long table (track, t, x0 ..), Parquet in ``out_dir``
    when given.  Returns ``run``'s result for the whole batch, equal to ``run(model, z)``:
    x the (B, T, n) states in z's dtype, read back from the chunks; the fields every track
    shares (P of the steady-state and FIR filters, inputs, method) from ``run`` on the
    first track; a field that differs from track to track is None.
    """
    require_model(model)
    z = _to_array("z", z)
    if z.ndim != 3:
        raise ShapeError(f"z: expected shape (B, T, m), got shape {z.shape}")
    sample = z.reshape(-1)[::max(1, z.size // 65536)]   # a fingerprint, not a full pass over z
    manifest = {"run": run.__qualname__, "model": _digest(model.F, model.H, model.Q, model.R),
                "shape": list(z.shape), "data": _digest(sample), "kwargs": repr(sorted(kwargs.items()))}
    df = run_chunks(_FilterTask(run, model, kwargs), z.shape[0], chunk_size=chunk_size, data=z,
                    out_dir=out_dir, executor=executor, max_workers=max_workers, client=client,
                    manifest=manifest, progress=progress)
    cols = [c for c in df.columns if c.startswith("x")]
    x = df[cols].to_numpy().reshape(z.shape[0], z.shape[1], len(cols))
    first = _filtered(run, model, z[:1], kwargs)
    shared = first.P is not None and first.P.strides[:2] == (0, 0)   # a view of one covariance
    P = _shared(first.P[0, 0], x, 1) if shared else None
    return BatchFilterResult(x=x, P=P, method=first.method, inputs=first.inputs)

