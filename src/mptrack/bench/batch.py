"""Benchmark suites of the batch engine (``mptrack bench --suite batch`` and ``batch-scaling``).

In one process and one run, on the same data: a memory copy moving the same
bytes as the kernel (read z + write x), the plain kernel (the simplest correct
compiled filter: batch-major, ``prange`` over tracks, state in registers, no
gaps, no checks), mptrack's batch functions as a user calls them, mptrack's
per-track reference, and FilterPy, pykalman and simdkalman where installed.
Every engine is first checked against mptrack on a common subset; only then
is it timed.

One update = one track, one time step, one filtered state.  Every ratio in the
reports is a throughput divided by an anchor's throughput measured in the same
run (above 1: faster than the anchor); no table mixes in time ratios.  The
copy is timed alternately with each engine, one call each, ``repeats`` times,
so both see the same machine load; a figure is the best throughput over the
copy's best, next to the median of the per-pair ratios and the same ratio in
CPU time on one numba thread (the work per core).
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import Callable

import numba as nb
import numpy as np
from numba.core import event as numba_event

from .. import batch, linear
from ..errors import ConvergenceError
from ..models import LinearGaussianModel, assimakis_model_a, assimakis_model_b
from ..riccati import steady_state
from . import register_suite
from ._timing import best_time, copy_kernel
from .linear import _filterpy, _pykalman  # the same peers as the 'linear' suite

__all__ = ["batch_suite", "batch_peers_suite", "batch_scaling_suite", "compile_times", "plain_kernel", "write_floor",
           "Anchor"]

AGREE_RTOL = 1e-8


@nb.njit(parallel=True, cache=True, nogil=True, boundscheck=False)
def plain_kernel(z, x, A, Bm):  # pragma: no cover - compiled
    """The anchor 'plain kernel': the steady-state filter of an n = 2, m = 1 model on z (B, T) into
    x (B, T, 2), batch-major, one track per ``prange`` iteration, the state in two registers,
    x(0/0) = 0, no missing values, lengths or checks -- what a user would write by hand."""
    a00, a01, a10, a11 = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    b0, b1 = Bm[0, 0], Bm[1, 0]
    for b in nb.prange(z.shape[0]):
        p = 0.0
        v = 0.0
        for t in range(z.shape[1]):
            zz = z[b, t]
            p, v = (a00 * p + a01 * v) + b0 * zz, (a10 * p + a11 * v) + b1 * zz
            x[b, t, 0] = p
            x[b, t, 1] = v


@nb.njit(parallel=True, cache=True, nogil=True, boundscheck=False)
def write_floor(z, x):  # pragma: no cover - compiled
    """A reference row: the filters' memory traffic with no arithmetic, x[b, t] = (z[b, t], z[b, t]) for
    z (B, T), x (B, T, 2), batch-major over the same threads -- the floor of any kernel that reads z
    and writes x with ordinary stores (each of which reads its line first; NumPy's copy does not)."""
    for b in nb.prange(z.shape[0]):
        for t in range(z.shape[1]):
            x[b, t, 0] = z[b, t]
            x[b, t, 1] = z[b, t]


class Anchor:
    """Times engines alternately with NumPy's copy of the same bytes (``np.copyto``, one thread:
    half the bytes read, half written), so that both see the same machine load."""

    def __init__(self, max_bytes: int):
        words = max(1, max_bytes // 16)
        self.src = np.ones(words)
        self.dst = np.ones(words)        # touched: no page faults in the copy's time

    def copy_seconds(self, nbytes: int) -> float:
        w = max(1, nbytes // 16)
        src, dst = self.src[:w], self.dst[:w]
        t0 = time.perf_counter()
        np.copyto(dst, src)
        return time.perf_counter() - t0

    def paired(self, fn: Callable[[], object], nbytes: int, repeats: int) -> tuple[np.ndarray, np.ndarray]:
        """Times (seconds) of ``repeats`` calls of ``fn`` and of the copy, alternately (after one
        untimed call of ``fn``)."""
        fn()
        t_fn, t_copy = np.empty(repeats), np.empty(repeats)
        for i in range(repeats):
            t0 = time.perf_counter()
            fn()
            t_fn[i] = time.perf_counter() - t0
            t_copy[i] = self.copy_seconds(nbytes)
        return t_fn, t_copy

    def paired_cpu(self, fn: Callable[[], object], nbytes: int, repeats: int) -> tuple[float, float]:
        """Best CPU times (seconds, ``time.process_time``) of ``fn`` on one numba thread and of the
        copy, alternately: the work per core, which the machine's other load barely changes."""
        previous = nb.get_num_threads()
        nb.set_num_threads(1)
        try:
            fn()
            t_fn = t_copy = np.inf
            for _ in range(repeats):
                c0 = time.process_time()
                fn()
                c1 = time.process_time()
                self.copy_seconds(nbytes)
                c2 = time.process_time()
                t_fn, t_copy = min(t_fn, c1 - c0), min(t_copy, c2 - c1)
        finally:
            nb.set_num_threads(previous)
        return t_fn, t_copy

    def parallel_copy(self, nbytes: int):
        """The same copy by all numba threads (a reference row: what two cores can move)."""
        w = max(1, nbytes // 16)
        src, dst = self.src[:w], self.dst[:w]
        return lambda: copy_kernel(src, dst)


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


def _coupled(model: LinearGaussianModel) -> LinearGaussianModel:
    """Model A with a process noise common to the first two axes' positions: not block diagonal, so
    the generic (n, m) kernel runs it (the rate of that kernel)."""
    v = np.zeros(model.n)
    v[[0, 2]] = 1.0
    return LinearGaussianModel(model.F, model.H, model.Q + 0.01 * np.outer(v, v), model.R, dt=model.dt,
                               name="model A, coupled axes")


def compile_times(dtypes=(np.float64, np.float32)) -> list[list]:
    """First call of each kernel on a tiny input in this process: compile (or cache load) time, and which
    of the two it was (numba's compile and compiler-lock events during the call)."""
    model_b, model_a = assimakis_model_b(), assimakis_model_a(2)
    cases = [
        ("steady-state n=2 m=1", lambda z: batch.steady_state_filter(model_b, z)),
        ("steady-state n=4 m=2 (generic)", lambda z: batch.steady_state_filter(_coupled(model_a),
                                                                                np.repeat(z, 2, axis=2))),
        ("Kalman n=2 m=1", lambda z: batch.kalman_filter(model_b, z)),
        ("FIR", lambda z: batch.fir_filter(model_b, z)),
    ]
    rows = []
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
        return dict(steps=400_000, T=200, sub_B=4, sub_T=100, simd_B=500, repeats=3)
    return dict(steps=10_000_000, T=1000, sub_B=20, sub_T=500, simd_B=10_000, repeats=9)


def _caches() -> dict[str, int]:
    """Data and unified cache sizes (bytes) of the first CPU, by level, from Linux's sysfs ({} elsewhere)."""
    sizes = {}
    for index in sorted(Path("/sys/devices/system/cpu/cpu0/cache").glob("index*")):
        try:
            kind = (index / "type").read_text().strip()
            level = (index / "level").read_text().strip()
            text = (index / "size").read_text().strip()
        except OSError:
            continue
        if kind != "Instruction" and text[:-1].isdigit():
            sizes[f"L{level}"] = int(text[:-1]) * {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(text[-1], 1)
    return sizes


def _load() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:  # pragma: no cover - no load average on this platform
        return float("nan")


def _engine_cases(s: dict, rng) -> tuple[list, dict]:
    """(name, shape text, bytes per update, updates, function, on the plain kernel's data) of every
    batch engine timed, and the agreement of the steady-state filter with the plain kernel."""
    T = s["T"]
    B = max(8, s["steps"] // T)
    model = assimakis_model_b()
    ss = steady_state(model)
    z = 10.0 * rng.standard_normal((B, T, 1))
    out = np.empty((B, T, 2))
    gains = batch.gain_sequence(model, T, np.eye(2))
    z32, out32 = z.astype(np.float32), np.empty((B, T, 2), np.float32)
    z2 = z[:, :, 0]
    A, Bm = np.ascontiguousarray(ss.A), np.ascontiguousarray(ss.B)
    plain_kernel(z2, out, A, Bm)
    agree = {"plain kernel": _check("plain kernel", out, batch.steady_state_filter(model, z, steady=ss).x)}
    upd = B * T
    full = f"{B}x{T}"
    cases = [
        ("plain kernel (anchor)", full, 24, upd, lambda: plain_kernel(z2, out, A, Bm), True),
        ("write floor: z read, x written, no arithmetic (reference)", full, 24, upd, lambda: write_floor(z2, out),
         True),
        ("batch SS f64, out=", full, 24, upd, lambda: batch.steady_state_filter(model, z, out=out), True),
        ("batch SS f64, allocating", full, 24, upd, lambda: batch.steady_state_filter(model, z), True),
        ("batch SS f32, out=", full, 12, upd, lambda: batch.steady_state_filter(model, z32, out=out32), True),
        ("batch KF shared gains f64, out=", full, 24, upd,
         lambda: batch.kalman_filter(model, z, out=out, gains=gains), True),
        ("batch KF shared gains f64, allocating", full, 24, upd,
         lambda: batch.kalman_filter(model, z, gains=gains), True),
        ("batch KF f64, out=, gains computed in the call", full, 24, upd,
         lambda: batch.kalman_filter(model, z, P0=np.eye(2), out=out), True),
        ("batch KF shared gains f32, out=", full, 12, upd,
         lambda: batch.kalman_filter(model, z32, out=out32, gains=gains), True),
    ]
    zx = z.reshape(B // 2, T, 2)             # the same bytes read as two-axis tracks
    outx = out.reshape(B // 2, T, 4)
    cases.append(("batch SS per axis (2 axes), out=", f"{B // 2}x{T}x2 axes", 24, upd,
                  lambda: batch.per_axis(batch.steady_state_filter, model, zx, out=outx), True))
    for axes in (2, 3):
        model_a = assimakis_model_a(axes)
        n, m = model_a.n, model_a.m
        Ba = max(8, s["steps"] // (T * axes))
        za = rng.standard_normal((Ba, T, m))
        outa = np.empty((Ba, T, n))
        cases.append((f"batch SS model A {axes}-D (n={n}, m={m}: its axes in time blocks), out=", f"{Ba}x{T}",
                      8 * (n + m), Ba * T, lambda model_a=model_a, za=za, outa=outa:
                      batch.steady_state_filter(model_a, za, out=outa), False))
        if axes == 2:
            ga = batch.gain_sequence(model_a, T, np.eye(n))
            cases.append((f"batch KF model A 2-D (n={n}, m={m}: its axes in time blocks), out=", f"{Ba}x{T}",
                          8 * (n + m), Ba * T, lambda model_a=model_a, za=za, outa=outa, ga=ga:
                          batch.kalman_filter(model_a, za, out=outa, gains=ga), False))
            coupled = _coupled(model_a)
            cases.append((f"batch SS coupled axes (n={n}, m={m}, generic kernel), out=", f"{Ba}x{T}",
                          8 * (n + m), Ba * T, lambda coupled=coupled, za=za, outa=outa:
                          batch.steady_state_filter(coupled, za, out=outa), False))
    M = linear.fir_order(ss.A)
    cases.append((f"batch FIR M={M}, out=", full, 24, upd,
                  lambda: batch.fir_filter(model, z, out=out, M=M, steady=ss), True))
    return cases, agree


@register_suite("batch")
def batch_suite(quick: bool) -> dict:
    """Batch kernels against the copy and the plain kernel; then per-track engines and peers."""
    s = _sizes(quick)
    reps = s["repeats"]
    rng = np.random.default_rng(2024)
    compile_rows = compile_times()
    load0 = _load()
    cases, agree = _engine_cases(s, rng)
    anchor = Anchor(max(c[2] * c[3] for c in cases))
    upd = cases[0][3]
    cases.insert(0, ("numba copy, all threads (reference)", cases[0][1], 24, upd, anchor.parallel_copy(24 * upd),
                     False))
    timed = {}
    for name, shape, nbytes, n_upd, fn, same_data in cases:
        t_fn, t_copy = anchor.paired(fn, nbytes * n_upd, reps)
        cpu_fn, cpu_copy = anchor.paired_cpu(fn, nbytes * n_upd, reps)
        timed[name] = (shape, nbytes, n_upd, t_fn, t_copy, cpu_copy / cpu_fn, same_data)
    plain_best = timed["plain kernel (anchor)"][3].min()
    rows = []
    for name, (shape, nbytes, n_upd, t_fn, t_copy, per_core, same_data) in timed.items():
        rows.append([name, shape, nbytes, n_upd / t_fn.min(), t_copy.min() / t_fn.min(),
                     float(np.median(t_copy / t_fn)), per_core, plain_best / t_fn.min() if same_data else None])
    del cases, anchor
    load1 = _load()
    notes = [
        "SS: steady-state filter, KF: Kalman filter (shared gain sequence); f32: float32 storage; "
        "'out=' writes into a given array, 'allocating' returns a new one",
        "x copy: updates/s over those of NumPy's copy (np.copyto, one thread) of the same bytes per update "
        "(z read + x written), each call timed alternately with the copy: best of the repeats over the "
        "copy's best, and the median of the per-pair ratios (steadier under load, lower when the other "
        "core is busy)",
        "x copy per core: the same ratio in CPU time with one numba thread (best of the repeats): the work "
        "per core, nearly independent of the machine's other load",
        "x plain kernel: best updates/s over the plain kernel's best, on the same model B data",
        f"{reps} repeats; {nb.get_num_threads()} numba threads; load average {load0:.2f} at the start, "
        f"{load1:.2f} at the end (the machine's other work slows the two-thread kernels more than the "
        "one-thread copy: on a loaded machine the ratios are low)",
        "first call per kernel (compile or cache load), seconds: "
        + "; ".join(f"{r[0]} {r[1]:.3g} ({r[2]})" for r in compile_rows),
        "agreement before timing (max |diff|): " + ", ".join(f"{k} {v:.2g}" for k, v in agree.items()),
    ]
    report = {"suite": "batch", "title": "Batch engine throughput, as a ratio to a memory copy (updates/s)",
              "columns": ["engine", "tracks x steps", "bytes/update", "updates/s (best)", "x copy (best)",
                          "x copy (median of pairs)", "x copy per core", "x plain kernel"],
              "rows": rows, "notes": notes,
              "compile": [{"kernel": r[0], "seconds": r[1], "source": r[2]} for r in compile_rows],
              "agreement": agree, "load": [load0, load1]}
    return report


@register_suite("batch-peers")
def batch_peers_suite(quick: bool) -> dict:
    """Per-track engines and the Python peers on subsets of one data set, as ratios to FilterPy,
    pykalman and simdkalman (throughput / the peer's throughput)."""
    s = _sizes(quick)
    rng = np.random.default_rng(2024)
    agree: dict[str, float] = {}
    reps = max(1, s["repeats"] // 3)
    model = assimakis_model_b()
    ss = steady_state(model)
    T = s["T"]
    x0, P0 = np.zeros(2), np.eye(2)
    zs = 10.0 * rng.standard_normal((s["simd_B"], T, 1))
    sub = np.ascontiguousarray(zs[: s["sub_B"], : s["sub_T"]])
    ss_sub = batch.steady_state_filter(model, sub, steady=ss).x
    kf_sub = batch.kalman_filter(model, sub, P0=P0).x
    agree["reference SS"] = _check("reference SS", np.stack(
        [linear.steady_state_filter(model, zb, steady=ss).x for zb in sub]), ss_sub)
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
    if peers["FilterPy"] is not None:   # FilterPy started at the steady-state covariance is the SS filter
        agree["FilterPy (P0 = Pe) vs SS"] = _check(
            "FilterPy SS", np.stack([_filterpy(model, zb, x0, ss.P_filt) for zb in sub]), ss_sub)
    sub_upd = sub.shape[0] * sub.shape[1]
    simd_upd = zs.shape[0] * T
    rates: dict[str, tuple[float, str]] = {}
    gains = batch.gain_sequence(model, T, P0)
    outs = np.empty((zs.shape[0], T, 2))
    rates["mptrack batch KF shared gains"] = (simd_upd / best_time(
        lambda: batch.kalman_filter(model, zs, out=outs, gains=gains), s["repeats"]), f"{zs.shape[0]}x{T}")
    rates["mptrack batch SS"] = (simd_upd / best_time(
        lambda: batch.steady_state_filter(model, zs, out=outs, steady=ss), s["repeats"]), f"{zs.shape[0]}x{T}")
    shape = f"{sub.shape[0]}x{sub.shape[1]}"
    rates["mptrack.linear SS per track"] = (sub_upd / best_time(
        lambda: [linear.steady_state_filter(model, zb, steady=ss) for zb in sub], reps), shape)
    rates["mptrack.linear KF per track"] = (sub_upd / best_time(
        lambda: [linear.kalman_filter(model, zb, P0=P0) for zb in sub], reps), shape)
    for name in ("FilterPy", "pykalman"):
        run = peers[name]
        if run is not None:
            rates[f"{name} KF per track"] = (sub_upd / best_time(
                lambda run=run: [run(model, zb, x0, P0) for zb in sub], reps), shape)
    if peers["simdkalman"] is not None:
        rates["simdkalman KF batch"] = (simd_upd / best_time(
            lambda: _simdkalman_run(model, zs, x0, P0), max(1, reps)), f"{zs.shape[0]}x{T}")
    anchors = {p: rates.get(k, (None,))[0] for p, k in (("FilterPy", "FilterPy KF per track"),
                                                        ("pykalman", "pykalman KF per track"),
                                                        ("simdkalman", "simdkalman KF batch"))}
    rows = [[name, shape, rate, *[None if a is None else rate / a for a in anchors.values()]]
            for name, (rate, shape) in rates.items()]
    notes = ["x peer: throughput / that of the peer (same run, same model B data; per-track engines on a "
             "subset, batch engines and simdkalman on a smaller batch); best of the repeats",
             "agreement before timing (max |diff|): " + ", ".join(f"{k} {v:.2g}" for k, v in agree.items())]
    missing = [p for p, run in peers.items() if run is None]
    if missing:
        notes.append("not installed (pip install 'mptrack[bench]'): " + ", ".join(missing))
    return {"suite": "batch-peers", "title": "mptrack against the Python Kalman filters (updates/s)",
            "columns": ["engine", "tracks x steps", "updates/s", "x FilterPy", "x pykalman", "x simdkalman"],
            "rows": rows, "notes": notes, "agreement": agree}


def _scaling_grid(quick: bool) -> tuple[list[int], list[int], int]:
    if quick:
        return [20, 200], [1, 16, 256, 2048], 1 << 20
    return [10, 100, 1000, 10_000], [4 ** k for k in range(0, 10)], 1 << 25


@register_suite("batch-scaling")
def batch_scaling_suite(quick: bool) -> dict:
    """Throughput vs batch size B and track length T (model B, float64, out=): the steady-state and
    shared-gain Kalman filters and the copy of the same bytes, timed alternately."""
    Ts, Bs, max_steps = _scaling_grid(quick)
    model = assimakis_model_b()
    ss = steady_state(model)
    rng = np.random.default_rng(7)
    load0 = _load()
    anchor = Anchor(24 * max_steps)
    rows = []
    for T in Ts:
        gains = batch.gain_sequence(model, T)
        for B in Bs:
            if B * T > max_steps:
                continue
            upd = B * T
            reps = int(np.clip((1 << 22) // upd, 3 if quick else 7, 60))   # more of the short calls
            z = rng.standard_normal((B, T, 1))
            out = np.empty((B, T, 2))
            nbytes = 24 * upd
            t_ss, c1 = anchor.paired(lambda: batch.steady_state_filter(model, z, out=out, steady=ss), nbytes, reps)
            t_kf, c2 = anchor.paired(lambda: batch.kalman_filter(model, z, out=out, gains=gains), nbytes, reps)
            copy = min(c1.min(), c2.min())
            rows.append([T, B, upd, upd / t_ss.min(), upd / t_kf.min(), upd / copy, copy / t_ss.min(),
                         copy / t_kf.min()])
    return {"suite": "batch-scaling", "title": "Throughput vs batch size and track length (model B, float64)",
            "columns": ["steps T", "tracks B", "updates", "steady-state updates/s",
                        "Kalman (shared gains) updates/s", "copy updates/s", "steady-state x copy",
                        "Kalman x copy"],
            "rows": rows, "caches": _caches(),
            "notes": [f"best of 7-60 alternating calls (more for short ones); copy: np.copyto of the same bytes; "
                      f"{nb.get_num_threads()} numba threads; batches below 2^20 output values run on one thread; "
                      "load average "
                      f"{load0:.2f} at the start, {_load():.2f} at the end"]}
