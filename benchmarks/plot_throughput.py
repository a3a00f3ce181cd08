"""Plot throughput (updates/s) vs batch size and track length from the ``batch-scaling`` suite.

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
    """Left: updates/s of the steady-state filter (solid) and of a copy of the same bytes (dashed)
    against the batch size B, one colour per track length T.  Right: the ratio of the two and
    that of the shared-gain Kalman filter (dotted).  Cache effects show as the copy's bump where
    the data fit in the cache; the one-thread rule for small batches as the kernels' step."""
    col = {name: i for i, name in enumerate(rep["columns"])}
    Ts = sorted({r[col["steps T"]] for r in rep["rows"]})
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, T in enumerate(Ts):
        rows = [r for r in rep["rows"] if r[col["steps T"]] == T]
        B = [r[col["tracks B"]] for r in rows]
        colour = f"C{i}"
        left.loglog(B, [r[col["steady-state updates/s"]] for r in rows], "o-", color=colour, label=f"T = {T}")
        left.loglog(B, [r[col["copy updates/s"]] for r in rows], "--", color=colour, alpha=0.6)
        right.semilogx(B, [r[col["steady-state x copy"]] for r in rows], "o-", color=colour, label=f"SS, T = {T}")
        right.semilogx(B, [r[col["Kalman x copy"]] for r in rows], "s:", color=colour, alpha=0.7)
    left.set_xlabel("tracks B")
    left.set_ylabel("updates/s (track-steps per second)")
    left.set_title("steady-state filter (solid) and copy (dashed)")
    right.axhline(1.0, color="k", lw=0.8)
    right.set_xlabel("tracks B")
    right.set_ylabel("throughput / copy of the same bytes")
    right.set_title("x copy: steady-state (solid), Kalman (dotted)")
    for ax in (left, right):
        ax.grid(True, which="both", alpha=0.3)
    left.legend(fontsize=8)
    fig.suptitle(rep["title"])
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
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
