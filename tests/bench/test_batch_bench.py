"""The batch bench suites run, check agreement before timing, and report ratios to same-run anchors."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from mptrack.bench import batch as bench_batch
from mptrack.bench import suites
from mptrack.errors import ConvergenceError

TINY = dict(steps=2000, T=40, sub_B=2, sub_T=20, simd_B=4, repeats=2)


def test_suites_are_registered():
    assert {"batch", "batch-peers", "batch-scaling"} <= set(suites())


def test_batch_suite_reports_rates_copy_ratios_with_spread_and_compile_times(monkeypatch):
    monkeypatch.setattr(bench_batch, "_sizes", lambda quick: TINY)
    # float64 only: the float32 signatures of the generic and FIR kernels are compiled by no test
    f64_only = bench_batch.compile_times
    monkeypatch.setattr(bench_batch, "compile_times", lambda: f64_only((np.float64,)))
    rep = bench_batch.batch_suite(True)
    col = {c: i for i, c in enumerate(rep["columns"])}
    names = [row[0] for row in rep["rows"]]
    assert names[0].startswith("numba copy")
    for name in ("plain kernel (anchor)", "batch SS f64, out=", "batch SS f64, allocating",
                 "batch KF shared gains f64, out=", "batch SS f32, out="):
        assert name in names
    assert any("model A 3-D" in n for n in names) and any("generic kernel" in n for n in names)
    for row in rep["rows"]:
        assert row[col["updates/s (best)"]] > 0 and row[col["x copy (best)"]] > 0
        assert row[col["x copy (median of pairs)"]] > 0 and row[col["x copy per core"]] > 0
    plain = next(r for r in rep["rows"] if r[0] == "plain kernel (anchor)")
    assert plain[col["x plain kernel"]] == 1.0
    # every figure is a throughput or a ratio of throughputs (higher is better): no times
    assert not any(word in c for c in rep["columns"] for word in ("time", "seconds", "us/", "ms"))
    assert rep["agreement"]["plain kernel"] < 1e-8
    assert all(r["seconds"] > 0 for r in rep["compile"])
    assert any("load average" in note for note in rep["notes"])


def test_peer_suite_checks_agreement_and_reports_rate_ratios(monkeypatch):
    monkeypatch.setattr(bench_batch, "_sizes", lambda quick: TINY)
    rep = bench_batch.batch_peers_suite(True)
    assert rep["columns"][3:] == ["x FilterPy", "x pykalman", "x simdkalman"]
    for peer in ("FilterPy", "pykalman", "simdkalman"):
        pytest.importorskip(peer.lower())
        assert rep["agreement"][peer] < 1e-8
    fp = next(r for r in rep["rows"] if r[0] == "FilterPy KF per track")
    assert fp[3] == 1.0


def test_a_peer_that_disagrees_stops_the_benchmark(monkeypatch):
    monkeypatch.setattr(bench_batch, "_sizes", lambda quick: TINY)
    monkeypatch.setattr(bench_batch, "_peer",
                        lambda name: (lambda model, z, x0, P0: np.zeros((z.shape[0], 2))))
    with pytest.raises(ConvergenceError, match="disagrees with mptrack.batch"):
        bench_batch.batch_peers_suite(True)


def test_scaling_suite_covers_batch_sizes_and_track_lengths(monkeypatch):
    monkeypatch.setattr(bench_batch, "_scaling_grid", lambda quick: ([10, 30], [1, 8], 10_000))
    rep = bench_batch.batch_scaling_suite(True)
    assert [(r[0], r[1]) for r in rep["rows"]] == [(10, 1), (10, 8), (30, 1), (30, 8)]
    assert all(v > 0 for r in rep["rows"] for v in r[3:])


def test_plot_throughput_writes_a_png(tmp_path):
    path = Path(__file__).parents[2] / "benchmarks" / "plot_throughput.py"
    spec = importlib.util.spec_from_file_location("plot_throughput", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rep = {"title": "t", "columns": ["steps T", "tracks B", "updates", "steady-state updates/s",
                                     "Kalman (shared gains) updates/s", "copy updates/s", "steady-state x copy",
                                     "Kalman x copy"],
           "rows": [[10, 1, 10, 5e7, 4e7, 1e8, 0.5, 0.4], [10, 16, 160, 1.5e8, 1e8, 2e8, 0.75, 0.5],
                    [100, 1, 100, 6e7, 5e7, 1e8, 0.6, 0.5]]}
    out = mod.plot(rep, tmp_path / "t.png")
    assert out.read_bytes()[:4] == b"\x89PNG"
