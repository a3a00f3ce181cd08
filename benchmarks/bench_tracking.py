"""Run the tracking benchmark suites and write their reports as JSON.

    python benchmarks/bench_tracking.py [--quick] [--out benchmarks/results/tracking.json]

Same suites as ``mptrack bench --suite tracking --suite tracking-accuracy``: end-to-end throughput
of ``mptrack track`` against the I/O floor measured in the same run, and the accuracy of the default
(noise estimated) against the oracle and the raw fixes (see src/mptrack/bench/tracking.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_batch import main as _main  # noqa: E402

if __name__ == "__main__":
    args = sys.argv[1:]
    if "--out" not in args:
        args += ["--out", "benchmarks/results/tracking.json"]
    if "--suite" not in args:
        args += ["--suite", "tracking", "--suite", "tracking-accuracy"]
    _main(args)
