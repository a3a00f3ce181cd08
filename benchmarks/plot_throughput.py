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

from mptrack._core.files import atomic_path  # noqa: E402
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
    """Left: updates/s of the steady-state (solid) and shared-gain Kalman (dotted) filters and of
    NumPy's copy of the same bytes (dashed) against the batch size B, one colour per track length
    T.  Right: the filters' throughput over the copy's against the bytes a call moves (24 per
    update), with the cache sizes: the copy gains where the data stay in a cache, the kernels
    where the call is long enough for both threads (the one-thread rule below 2^20 values)."""
    col = {name: i for i, name in enumerate(rep["columns"])}
    Ts = sorted({r[col["steps T"]] for r in rep["rows"]})
    fig, (left, right) = plt.subplots(1, 2, figsize=(11.5, 4.4))
    for i, T in enumerate(Ts):
        rows = [r for r in rep["rows"] if r[col["steps T"]] == T]
        B = [r[col["tracks B"]] for r in rows]
        moved = [24 * r[col["updates"]] for r in rows]
        colour = f"C{i}"
        left.loglog(B, [r[col["steady-state updates/s"]] for r in rows], "o-", color=colour, label=f"T = {T}")
        left.loglog(B, [r[col["Kalman (shared gains) updates/s"]] for r in rows], ":", color=colour)
        left.loglog(B, [r[col["copy updates/s"]] for r in rows], "--", color=colour, alpha=0.6)
        right.semilogx(moved, [r[col["steady-state x copy"]] for r in rows], "o-", color=colour, label=f"T = {T}")
        right.semilogx(moved, [r[col["Kalman x copy"]] for r in rows], "s:", color=colour, alpha=0.7)
    right.axhline(1.0, color="k", lw=0.8)
    for level, size in sorted(rep.get("caches", {}).items()):
        if level != "L1":
            right.axvline(size, color="grey", lw=0.8, ls="--")
            right.text(size, right.get_ylim()[1], f" {level} {size >> 20} MiB", va="top", fontsize=8, color="grey")
    left.set_xlabel("tracks B")
    left.set_ylabel("updates/s (track-steps per second)")
    left.set_title("steady-state (solid), Kalman (dotted), copy (dashed)", fontsize=10)
    right.set_xlabel("bytes moved per call (z read + x written)")
    right.set_ylabel("throughput / NumPy copy of the same bytes")
    right.set_title("x copy: steady-state (solid), Kalman (dotted)", fontsize=10)
    for ax in (left, right):
        ax.grid(True, which="both", alpha=0.3)
    left.legend(fontsize=8)
    fig.suptitle(rep["title"], fontsize=11)
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
