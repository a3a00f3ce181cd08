"""Per-iteration timing of the 12 implementations and of the KF against FilterPy/pykalman.

    python benchmarks/bench_linear.py [--quick] [--json results/linear.json]

Same as ``mptrack bench --suite linear``; kept here so the benchmark suite can
be run without the CLI.
"""

import argparse
import json

from mptrack.bench import run_suites

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    (report,) = run_suites(["linear"], quick=args.quick)
    for row in report["rows"]:
        print(" | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row))
    for note in report["notes"]:
        print(note)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=2)
