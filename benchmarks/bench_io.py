"""Run the I/O benchmark suite and write its report as JSON.

    python benchmarks/bench_io.py [--quick] [--out benchmarks/results/io.json]

Same suite as ``mptrack bench --suite io``: reading 10^6 fixes from CSV and Parquet through mptrack's
reader next to pandas, and writing each output format next to ``DataFrame.to_parquet``, in the same
run (see src/mptrack/bench/io.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_batch import main as _main  # noqa: E402

if __name__ == "__main__":
    args = sys.argv[1:]
    if "--out" not in args:
        args += ["--out", "benchmarks/results/io.json"]
    if "--suite" not in args:
        args += ["--suite", "io"]
    _main(args)
