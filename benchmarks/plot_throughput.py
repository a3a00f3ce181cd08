"""Plot throughput (updates/s) vs batch size from the ``batch-scaling`` suite.

    python benchmarks/plot_throughput.py [--json benchmarks/results/batch.json] [--quick]
                                         [--out benchmarks/results/throughput.png]

Reads the suite's report from the JSON written by bench_batch.py when given,
otherwise runs the suite now.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from mptrack._io import atomic_path  # noqa: E402
from mptrack.bench import run_suites  # noqa: E402


def scaling_report(json_path: Path | None, quick: bool) -> dict:
    if json_path is not None:
        reports = json.loads(json_path.read_text())["reports"]
        for rep in reports:
            if rep["suite"] == "batch-scaling":
                return rep
        raise SystemExit(f"{json_path}: no batch-scaling report in it")
    return run_suites(["batch-scaling"], quick=quick)[0]


def plot(rep: dict, out: Path) -> Path:
    rows = rep["rows"]
    B = [r[0] for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for j, style in ((2, "k--"), (3, "o-"), (4, "s-")):
        ax.loglog(B, [r[j] for r in rows], style, label=rep["columns"][j].replace(" updates/s", ""))
    ax.set_xlabel(f"tracks B (T = {rows[0][1]} steps each)")
    ax.set_ylabel("updates/s (track-steps per second)")
    ax.set_title(rep["title"])
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return out


def main(argv=None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/throughput.png"))
    args = parser.parse_args(argv)
    path = plot(scaling_report(args.json, args.quick), args.out)
    print(f"wrote {path}")
    return path


if __name__ == "__main__":
    main()
