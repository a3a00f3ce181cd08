"""Benchmark suites of the batch engine (``mptrack bench --suite batch``).

In one process and one run, on the same data: a memory-copy baseline moving
the same bytes as the kernel (read z + write x), mptrack's batch kernels,
mptrack's per-track reference, and FilterPy, pykalman and simdkalman where
installed.  Every engine is first checked against mptrack on a common subset;
only then is it timed.  Rates are updates/s (one update = one track, one time
step, one filtered state), best of a few repeats.
"""

from __future__ import annotations

import contextlib
import time
from typing import Callable

import numpy as np
from numba.core import event as numba_event

from .. import batch, linear
from ..errors import ConvergenceError
from ..models import assimakis_model_a, assimakis_model_b
from ..riccati import steady_state
from . import register_suite
from ._timing import best_time, copy_kernel
from .linear import _filterpy, _pykalman  # the same peers as the 'linear' suite

__all__ = ["batch_suite", "batch_scaling_suite", "compile_times"]

AGREE_RTOL = 1e-8


class _Copier:
    """The memory-copy baseline: buffers for up to ``max_bytes`` of traffic (read half, write half)."""

    def __init__(self, max_bytes: int):
        words = max(1, max_bytes // 16)
        self.src = np.ones(words)
        self.dst = np.empty(words)
        copy_kernel(self.src[:1], self.dst[:1])

    def copy_seconds(self, nbytes: int) -> float:
        """Time of the faster of memcpy (numpy) and a parallel numba copy moving ``nbytes``."""
        w = max(1, nbytes // 16)
        src, dst = self.src[:w], self.dst[:w]
        t0 = time.perf_counter()
        np.copyto(dst, src)
        t1 = time.perf_counter()
        copy_kernel(src, dst)
        return min(t1 - t0, time.perf_counter() - t1)

    def paired(self, fn: Callable[[], object], nbytes: int, repeats: int) -> tuple[float, float]:
        """Best times of ``fn`` and of the copy, run alternately (so both see the same machine load)."""
        fn()
        t_fn = t_copy = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            t_fn = min(t_fn, time.perf_counter() - t0)
            t_copy = min(t_copy, self.copy_seconds(nbytes))
        return t_fn, t_copy


class _Compiles(numba_event.Listener):
    """Counts numba's compilations and its compiler-lock acquisitions (a compilation, or a signature
    loaded from the cache; a signature already in memory takes neither)."""

    def __init__(self):
        self.counts = {"numba:compile": 0, "numba:compiler_lock": 0}

    def on_start(self, event):
        self.counts[event.kind] += 1

    def on_end(self, event):
        pass

    def how(self, before: dict) -> str:
        if self.counts["numba:compile"] > before["numba:compile"]:
            return "compiled"
        return "numba cache" if self.counts["numba:compiler_lock"] > before["numba:compiler_lock"] \
            else "already in memory"


def compile_times(dtypes=(np.float64, np.float32)) -> list[list]:
    """First call of each kernel on a tiny input in this process: compile (or cache load) time, and which
    of the two it was (numba's compile and compiler-lock events during the call)."""
    model_b, model_a = assimakis_model_b(), assimakis_model_a(2)
    rows = []
    cases = [
        ("steady-state n=2 m=1", lambda z: batch.steady_state_filter(model_b, z)),
        ("steady-state generic", lambda z: batch.steady_state_filter(model_a, np.repeat(z, 2, axis=2))),
        ("Kalman n=2 m=1", lambda z: batch.kalman_filter(model_b, z)),
        ("FIR", lambda z: batch.fir_filter(model_b, z)),
    ]
    events = _Compiles()
    with contextlib.ExitStack() as stack:
        for kind in events.counts:
            stack.enter_context(numba_event.install_listener(kind, events))
        for name, fn in cases:
            for dtype in dtypes:
                before = dict(events.counts)
                t0 = time.perf_counter()
                fn(np.zeros((2, 3, 1), dtype=dtype))
                seconds = time.perf_counter() - t0
                rows.append([f"{name} {np.dtype(dtype).name}", seconds, events.how(before)])
    return rows


def _simdkalman_run(model, z, x0, P0):
    import simdkalman

    kf = simdkalman.KalmanFilter(state_transition=model.F, process_noise=model.Q,
                                 observation_model=model.H, observation_noise=model.R)
    data = z[..., 0] if model.m == 1 else z
    res = kf.compute(data, 0, initial_value=model.F @ x0,
                     initial_covariance=model.F @ P0 @ model.F.T + model.Q,
                     smoothed=False, filtered=True, covariances=False, observations=False)
    return res.filtered.states.mean


def _peer(name: str):
    try:
        __import__({"FilterPy": "filterpy", "pykalman": "pykalman", "simdkalman": "simdkalman"}[name])
    except ImportError:
        return None
    return {"FilterPy": _filterpy, "pykalman": _pykalman, "simdkalman": _simdkalman_run}[name]


def _check(name: str, got: np.ndarray, want: np.ndarray) -> float:
    diff = float(np.max(np.abs(got - want)))
    scale = max(1.0, float(np.max(np.abs(want))))
    if not diff <= AGREE_RTOL * scale:
        raise ConvergenceError(
            f"bench: {name} disagrees with mptrack.batch by {diff:.3g} (scale {scale:.3g})")
    return diff


def _sizes(quick: bool) -> dict:
    if quick:
        return dict(B=2000, T=200, sub_B=4, sub_T=100, simd_B=500, repeats=2)
    return dict(B=100_000, T=1000, sub_B=20, sub_T=500, simd_B=10_000, repeats=5)


@register_suite("batch")
def batch_suite(quick: bool) -> dict:
    """Batch kernels vs the copy baseline, the per-track reference and the Python peers."""
    s = _sizes(quick)
    B, T, reps = s["B"], s["T"], s["repeats"]
    model = assimakis_model_b()
    ss = steady_state(model)
    rng = np.random.default_rng(2024)
    compile_rows = compile_times()

    # data: z (B, T, 1), the filters' prior x(0/0) = 0; the KF starts from P0 = I
    z = 10.0 * rng.standard_normal((B, T, 1))
    out = np.empty((B, T, 2))
    x0, P0 = np.zeros(2), np.eye(2)
    gains = batch.gain_sequence(model, T, P0)

    # agreement on a common subset before any timing
    sub = np.ascontiguousarray(z[: s["sub_B"], : s["sub_T"]])
    ss_sub = batch.steady_state_filter(model, sub, steady=ss)
    kf_sub = batch.kalman_filter(model, sub, P0=P0)
    agree = {"reference SS": _check("reference SS", np.stack(
        [linear.steady_state_filter(model, zb, steady=ss).x for zb in sub]), ss_sub)}
    agree["reference KF"] = _check("reference KF", np.stack(
        [linear.kalman_filter(model, zb, P0=P0).x for zb in sub]), kf_sub)
    peers = {name: _peer(name) for name in ("FilterPy", "pykalman", "simdkalman")}
    for name, run in peers.items():
        if run is None:
            continue
        if name == "simdkalman":
            agree[name] = _check(name, run(model, sub, x0, P0), kf_sub)
        else:
            agree[name] = _check(name, np.stack([run(model, zb, x0, P0) for zb in sub]), kf_sub)
    # FilterPy started at the steady-state covariance is the steady-state filter
    if peers["FilterPy"] is not None:
        agree["FilterPy (P0 = Pe) vs SS"] = _check(
            "FilterPy SS", np.stack([_filterpy(model, zb, x0, ss.P_filt) for zb in sub]), ss_sub)

    updates = B * T
    copier = _Copier(24 * updates)
    rates: dict[str, tuple] = {}     # name -> (updates/s, copy updates/s of the same bytes or None, data)

    def paired(name, fn, nbytes, shape, n_upd=updates):
        t_fn, t_copy = copier.paired(fn, nbytes * n_upd, reps)
        rates[name] = (n_upd / t_fn, n_upd / t_copy, shape)

    full = f"{B}x{T}"
    z32, out32 = z.astype(np.float32), np.empty((B, T, 2), np.float32)
    paired("batch SS f64", lambda: batch.steady_state_filter(model, z, out=out, steady=ss), 24, full)
    paired("batch SS f32", lambda: batch.steady_state_filter(model, z32, out=out32, steady=ss), 12, full)
    paired("batch KF shared gains", lambda: batch.kalman_filter(model, z, out=out, gains=gains), 24, full)
    paired("batch KF shared gains f32",
           lambda: batch.kalman_filter(model, z32, out=out32, gains=gains), 12, full)
    del z32, out32
    zA = z.reshape(B // 2, T, 2)     # the same bytes read as two-axis tracks
    outA = out.reshape(B // 2, T, 4)
    paired("batch SS per-axis (2 axes)",
           lambda: batch.per_axis(batch.steady_state_filter, model, zA, out=outA, steady=ss), 24,
           f"{B // 2}x{T}x2 axes")
    model_a = assimakis_model_a(2)
    ss_a = steady_state(model_a)
    paired("batch SS model A (generic)",
           lambda: batch.steady_state_filter(model_a, zA, out=outA, steady=ss_a), 24,
           f"{B // 2}x{T} (n=4, m=2)")
    M = linear.fir_order(ss.A)
    paired(f"batch FIR M={M}", lambda: batch.fir_filter(model, z, out=out, M=M, steady=ss), 24, full)
    del zA, outA

    # per-track engines on the subset (they are 10^3-10^5 times slower)
    sub_upd = sub.shape[0] * sub.shape[1]
    sub_shape = f"{sub.shape[0]}x{sub.shape[1]}"
    rates["reference SS per track"] = (sub_upd / best_time(
        lambda: [linear.steady_state_filter(model, zb, steady=ss) for zb in sub], reps), None, sub_shape)
    rates["reference KF per track"] = (sub_upd / best_time(
        lambda: [linear.kalman_filter(model, zb, P0=P0) for zb in sub], reps), None, sub_shape)
    for name in ("FilterPy", "pykalman"):
        run = peers[name]
        if run is not None:
            rates[f"{name} KF per track"] = (sub_upd / best_time(
                lambda run=run: [run(model, zb, x0, P0) for zb in sub], reps), None, sub_shape)
    if peers["simdkalman"] is not None:
        zs = np.ascontiguousarray(z[: s["simd_B"]])
        outs = np.empty((zs.shape[0], T, 2))
        n_simd = zs.shape[0] * T
        rates["simdkalman KF batch"] = (n_simd / best_time(
            lambda: _simdkalman_run(model, zs, x0, P0), max(1, reps - 2)), None, f"{zs.shape[0]}x{T}")
        paired("batch KF (simdkalman batch)", lambda: batch.kalman_filter(model, zs, out=outs, gains=gains),
               24, f"{zs.shape[0]}x{T}", n_simd)
    del z, out, copier

    peer_rate = {p: rates.get(f"{p} KF per track", (None,))[0] for p in ("FilterPy", "pykalman")}
    peer_rate["simdkalman"] = rates.get("simdkalman KF batch", (None,))[0]

    def ratio(r, p):
        return None if p is None else r / p

    def peer_ratios(r):
        return [ratio(r, peer_rate[p]) for p in ("FilterPy", "pykalman", "simdkalman")]

    best_copy: dict[str, float] = {}
    for name, (rate, crate, shape) in rates.items():
        if crate is not None and shape == full:
            key = "12" if name.endswith("f32") else "24"
            best_copy[key] = max(best_copy.get(key, 0.0), crate)
    rows = [[f"memory copy {k} B/upd", full, c, 1.0, *peer_ratios(c)] for k, c in sorted(best_copy.items())]
    for name, (rate, crate, shape) in rates.items():
        rows.append([name, shape, rate, ratio(rate, crate), *peer_ratios(rate)])
    notes = ["SS: steady-state filter, KF: Kalman filter; f32: float32 storage",
             f"model B (n=2, m=1, H printed), float64 unless noted; best of {reps} runs; "
             f"{_numba_threads()} numba threads",
             "x copy: updates/s over that of a copy moving the same bytes (read z + write x), timed "
             "alternately with the kernel (best of each); copy rows: the best copy rate seen",
             "per-track engines and pykalman/FilterPy timed on a subset (same data), simdkalman on a "
             "smaller batch; mptrack is timed on that same batch for the simdkalman ratio",
             "agreement before timing (max |diff|): " + ", ".join(f"{k} {v:.2g}" for k, v in agree.items()),
             "first call per kernel (compile or cache load), seconds: "
             + "; ".join(f"{r[0]} {r[1]:.3g} ({r[2]})" for r in compile_rows)]
    missing = [p for p, run in peers.items() if run is None]
    if missing:
        notes.append("not installed (pip install 'mptrack[bench]'): " + ", ".join(missing))
    return {"suite": "batch", "title": "Batch engine throughput (updates/s)",
            "columns": ["engine", "tracks x steps", "updates/s", "x copy", "x FilterPy", "x pykalman",
                        "x simdkalman"],
            "rows": rows, "notes": notes,
            "compile": [{"kernel": r[0], "seconds": r[1], "source": r[2]} for r in compile_rows],
            "agreement": agree}


def _numba_threads() -> int:
    import numba

    return numba.get_num_threads()


@register_suite("batch-scaling")
def batch_scaling_suite(quick: bool) -> dict:
    """Throughput vs batch size B (T fixed) for the SS and shared-gain KF kernels and the copy."""
    T = 200 if quick else 1000
    sizes = [1, 4, 16, 64, 256, 1024] if quick else [1, 4, 16, 64, 256, 1024, 4096, 16384, 65536]
    reps = 5
    model = assimakis_model_b()
    ss = steady_state(model)
    gains = batch.gain_sequence(model, T)
    rng = np.random.default_rng(7)
    rows = []
    for B in sizes:
        z = rng.standard_normal((B, T, 1))
        out = np.empty((B, T, 2))
        copier = _Copier(24 * B * T)
        nbytes = 24 * B * T
        t_ss, c1 = copier.paired(lambda: batch.steady_state_filter(model, z, out=out, steady=ss), nbytes, reps)
        t_kf, c2 = copier.paired(lambda: batch.kalman_filter(model, z, out=out, gains=gains), nbytes, reps)
        r_ss, r_kf, r_copy = B * T / t_ss, B * T / t_kf, B * T / min(c1, c2)
        rows.append([B, T, r_copy, r_ss, r_kf])
    return {"suite": "batch-scaling", "title": "Throughput vs batch size (model B, float64)",
            "columns": ["tracks B", "steps T", "copy updates/s", "steady-state updates/s",
                        "Kalman (shared gains) updates/s"],
            "rows": rows,
            "notes": [f"best of {reps}; {_numba_threads()} numba threads; batches below 2^20 output "
                      "values run on one thread; small batches fit in cache (the copy too)"]}
