"""Studies with the batch filters, run in chunks by :mod:`mptrack.runs`: Monte-Carlo simulation and
filtering of a batch larger than memory, on any executor, resumable.

Run ``i`` of a study draws from its own stream (:class:`mptrack.runs.Chunk`), so the numbers depend
on the seed only, not on the chunking or the executor.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np
import pandas as pd

from .._core.validation import _to_array, check_allocation, check_covariance, check_int
from ..errors import DTypeError, ParameterError, ShapeError
from ..models import LinearGaussianModel, require_model
from ..result import BatchFilterResult
from ..runs import Chunk, run_chunks
from ._filters import _shared, gain_sequence, kalman_filter, steady_state_filter

__all__ = ["MonteCarloTask", "monte_carlo", "filter_chunked"]


def _digest(*arrays) -> str:
    """A short fingerprint of arrays' contents, to tell one study's chunks from another's."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


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
                chunk_size: int = 1000, executor: str = "serial", out_dir=None,
                max_workers: int | None = None, client=None, progress=None) -> pd.DataFrame:
    """A Monte-Carlo study of simulated tracks, filtered with the batch engine in chunks.

    Run i draws its process and measurement noise from its own stream, exactly as
    :func:`mptrack.sim.simulate_linear`, so the numbers depend on ``seed`` only.

    Parameters
    ----------
    model : LinearGaussianModel
    steps : int
        Steps per run.
    runs : int
        Number of runs.
    seed : int
        The study's root entropy.
    method : {"steady-state", "kalman"}, optional
    P0 : array_like, shape (n, n), optional
        The Kalman filter's prior covariance.
    chunk_size : int, optional
        Runs per chunk.
    executor : {"serial", "processes", "dask"}, optional
        Who runs the chunks: this process, a spawn-context ProcessPoolExecutor, or a Dask cluster
        (``client``, or a LocalCluster started for the call; install ``mptrack[dask]``).
    max_workers : int, optional
        Processes or Dask workers (default: the cores).
    client : dask.distributed.Client, optional
    out_dir : str or path-like, optional
        Resumable Parquet output (:func:`mptrack.runs.run_chunks`).
    progress : callable, optional
        ``progress(k)`` each time k more chunks are done (skipped ones included).

    Returns
    -------
    pandas.DataFrame
        One row per run: ``run`` and the RMSE over time of each state component (``rmse_x0``, ...).
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
                   executor: str = "serial", out_dir=None, max_workers: int | None = None,
                   client=None, progress=None, **kwargs) -> BatchFilterResult:
    """Filter a batch larger than memory in chunks of tracks with a batch filter.

    Each chunk's states go to a long table (track, t, x0 ..), Parquet in ``out_dir`` when given.

    Parameters
    ----------
    run : callable
        A batch filter (e.g. :func:`steady_state_filter`).
    model : LinearGaussianModel
    z : array_like, shape (B, T, m)
    chunk_size : int
        Tracks per chunk.
    executor : {"serial", "processes", "dask"}, optional
        Who runs the chunks: this process, a spawn-context ProcessPoolExecutor, or a Dask cluster
        (``client``, or a LocalCluster started for the call; install ``mptrack[dask]``).
    max_workers : int, optional
        Processes or Dask workers (default: the cores).
    client : dask.distributed.Client, optional
    out_dir : str or path-like, optional
        Resumable output; another study's directory is refused.
    progress : callable, optional
        ``progress(k)`` each time k more chunks are done (skipped ones included).
    **kwargs
        Passed to ``run``.

    Returns
    -------
    BatchFilterResult
        Equal to ``run(model, z)``: x read back from the chunks; the fields every track shares (P of the
        steady-state and FIR filters, inputs, method) from ``run`` on the first track; others None.
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

