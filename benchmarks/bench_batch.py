"""Run the batch-engine benchmark suites and write their reports as JSON.

    python benchmarks/bench_batch.py [--quick] [--out benchmarks/results/batch.json]

Same suites as ``mptrack bench --suite batch --suite batch-peers --suite batch-scaling``; the JSON
holds {"reports": [...]} with the table rows, notes, compile times and the
agreement check of every engine (see src/mptrack/bench/batch.py).
"""

from __future__ import annotations

import argparse
import os
import platform
from pathlib import Path

from mptrack import __version__
from mptrack._core.files import write_json
from mptrack.bench import run_suites


def main(argv=None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (seconds)")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/batch.json"))
    parser.add_argument("--suite", action="append", help="suites to run (default: batch, batch-peers, batch-scaling)")
    args = parser.parse_args(argv)
    reports = run_suites(args.suite or ["batch", "batch-peers", "batch-scaling"], quick=args.quick)
    for rep in reports:
        print(f"\n{rep['suite']}: {rep['title']}")
        print(" | ".join(rep["columns"]))
        for row in rep["rows"]:
            print(" | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row))
        for note in rep["notes"]:
            print("  " + note)
    import numba
    import numpy

    meta = {"mptrack_version": __version__, "python": platform.python_version(), "numpy": numpy.__version__,
            "numba": numba.__version__, "machine": platform.machine(), "processor": platform.processor(),
            "cpus": os.cpu_count(), "numba_threads": numba.get_num_threads(),
            "load_average_at_end": list(os.getloadavg()), "quick": args.quick}
    write_json(args.out, {"meta": meta, "reports": reports})
    print(f"\nwrote {args.out}")
    return args.out


if __name__ == "__main__":
    main()
