"""The batch bench suites run, check agreement before timing, and report ratios."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from mptrack.bench import batch as bench_batch
from mptrack.bench import suites
from mptrack.errors import ConvergenceError

TINY = dict(B=8, T=30, sub_B=2, sub_T=20, simd_B=4, repeats=1)


def test_suites_are_registered():
    assert {"batch", "batch-scaling"} <= set(suites())


def test_batch_suite_reports_rates_ratios_agreement_and_compile_times(monkeypatch):
    monkeypatch.setattr(bench_batch, "_sizes", lambda quick: TINY)
    # float64 only: the float32 signatures of the generic and FIR kernels are compiled by no test
    f64_only = bench_batch.compile_times
    monkeypatch.setattr(bench_batch, "compile_times", lambda: f64_only((np.float64,)))
    rep = bench_batch.batch_suite(True)
    names = [row[0] for row in rep["rows"]]
    assert names[0].startswith("memory copy")
    assert "batch SS f64" in names and "batch KF shared gains" in names
    for row in rep["rows"]:
        assert row[2] > 0                      # updates/s
    copy_row = next(r for r in rep["rows"] if r[0] == "memory copy 24 B/upd")
    assert copy_row[3] == 1.0
    for peer in ("FilterPy", "pykalman", "simdkalman"):
        pytest.importorskip(peer.lower())
        assert rep["agreement"][peer] < 1e-8
    assert all(r["seconds"] > 0 for r in rep["compile"])


def test_a_peer_that_disagrees_stops_the_benchmark(monkeypatch):
    monkeypatch.setattr(bench_batch, "_sizes", lambda quick: TINY)
    monkeypatch.setattr(bench_batch, "compile_times", lambda: [])
    monkeypatch.setattr(bench_batch, "_peer",
                        lambda name: (lambda model, z, x0, P0: np.zeros((z.shape[0], 2))))
    with pytest.raises(ConvergenceError, match="disagrees with mptrack.batch"):
        bench_batch.batch_suite(True)


def test_plot_throughput_writes_a_png(tmp_path):
    path = Path(__file__).parents[2] / "benchmarks" / "plot_throughput.py"
    spec = importlib.util.spec_from_file_location("plot_throughput", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rep = {"title": "t", "columns": ["tracks B", "steps T", "copy updates/s", "steady-state updates/s",
                                     "Kalman (shared gains) updates/s"],
           "rows": [[1, 10, 1e8, 5e7, 4e7], [16, 10, 2e8, 1.5e8, 1e8]]}
    out = mod.plot(rep, tmp_path / "t.png")
    assert out.read_bytes()[:4] == b"\x89PNG"
