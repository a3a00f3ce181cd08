"""The ``mptrack`` command line, generated from the registries."""

from __future__ import annotations

import os

# mptrack's matrices are small (n <= 10): BLAS threads only add synchronisation cost
# (milliseconds per call on a loaded machine). Parallelism is over tracks (numba).
# Set before NumPy is imported; a value the user exported is kept.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path  # noqa: E402
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table as RichTable

from .errors import MptrackError

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="mptrack: mobile-terminal position tracking and paper reproductions.")
console = Console()
err_console = Console(stderr=True)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return "—" if v is None else str(v)


def print_reproduction(rep, con: Console = console) -> None:
    """Each table with our numbers and the paper's side by side; differing cells flagged."""
    con.rule(f"[bold]{rep.key}[/bold] — {rep.paper}")
    for label, table in rep.tables.items():
        bad = set(table.mismatches())
        rt = RichTable(title=f"{label}: {table.title}", title_justify="left")
        rt.add_column(table.columns[0])
        for col in table.columns[1:]:
            rt.add_column(f"{col}" + (" (ours | paper)" if table.paper is not None else ""), justify="right")
        for i, row in enumerate(table.rows):
            cells = [str(row[0])]
            for j in range(1, len(row)):
                ours = _fmt(row[j])
                if table.paper is None or table.paper[i][j] is None:
                    cells.append(ours)
                elif not isinstance(row[j], (int, float)) and (i, j) not in bad:
                    cells.append(ours)  # identical text (a formula, a label): show it once
                else:
                    mark = "[red]≠[/red]" if (i, j) in bad else "[green]=[/green]"
                    cells.append(f"{ours} {mark} {_fmt(table.paper[i][j])}")
            rt.add_row(*cells)
        con.print(rt)
        if table.notes:
            con.print(f"[dim]{table.notes}[/dim]")
    for name, path in rep.figures.items():
        con.print(f"{name}: {path}")
    for note in rep.notes:
        con.print(f"[yellow]note:[/yellow] {note}")


@app.command()
def reproduce(
    key: Optional[str] = typer.Argument(None, help="Reproduction key, or 'all'."),
    out: Path = typer.Option(Path("mptrack-results"), "--out", help="Output root; results go to OUT/KEY/."),
    seed: Optional[int] = typer.Option(None, help="Override the reproduction's default seed."),
    list_: bool = typer.Option(False, "--list", help="List the reproduction keys and exit."),
    quick: bool = typer.Option(False, help="Reduced Monte-Carlo sizes (for smoke tests)."),
    resume: bool = typer.Option(True, help="Reuse finished parts cached under OUT/KEY/.cache."),
    quiet: bool = typer.Option(False, help="No tables or progress bars; only the summary."),
) -> None:
    """Reproduce a paper's tables and figures, side by side with the published numbers."""
    from ._progress import RichProgress
    from .experiments import experiments, run_experiment

    reg = experiments()
    if list_ or key is None:
        for k, exp in reg.items():
            console.print(f"[bold]{k}[/bold]  {exp.paper}\n    {exp.description}")
        return
    todo = list(reg) if key == "all" else [key]
    failed = []
    for k in todo:
        try:
            with RichProgress(console=err_console, disable=quiet) as progress:
                rep = run_experiment(k, out, seed=seed, quick=quick, resume=resume, progress=progress)
        except MptrackError as exc:
            err_console.print(f"[red]error:[/red] {exc}")
            raise typer.Exit(2) from None
        if not quiet:
            print_reproduction(rep)
        n_bad = sum(1 for t in rep.tables.values() for i, j in t.mismatches()
                    if isinstance(t.paper[i][j], (int, float)))
        n_cells = sum(1 for t in rep.tables.values() if t.paper is not None
                      for r in t.paper for v in r[1:] if isinstance(v, (int, float)))
        console.print(f"[bold]{k}[/bold]: {len(rep.tables)} tables, {n_cells - n_bad}/{n_cells} published "
                      f"numbers reproduced, {len(rep.figures)} figures, {rep.elapsed_s:.1f} s → "
                      f"{out / k / 'results.json'}")
        if n_bad:
            failed.append(k)
    if failed:
        console.print(f"[yellow]differences from the paper in: {', '.join(failed)} "
                      "(see the tables and docs/errata.md)[/yellow]")


@app.command()
def filters() -> None:
    """List the registered filters and the 12 implementations of seed 000 Table 1."""
    from .linear import FILTERS, IMPLEMENTATIONS

    rt = RichTable(title="Filters")
    for col in ("name", "system", "description"):
        rt.add_column(col)
    for spec in FILTERS.values():
        rt.add_row(spec.name, spec.system, spec.description)
    console.print(rt)
    rt = RichTable(title="Implementations (seed 000 Table 1)")
    for col in ("#", "name", "model", "system", "filter"):
        rt.add_column(col)
    for imp in IMPLEMENTATIONS:
        rt.add_row(str(imp.number), imp.name, imp.model, imp.system, imp.filter)
    console.print(rt)


@app.command()
def bench(
    quick: bool = typer.Option(False, help="Small sizes, a few seconds."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the results as JSON to this file."),
    suite: Optional[list[str]] = typer.Option(None, help="Run only these suites (repeatable)."),
) -> None:
    """Benchmark mptrack against a memory-copy baseline and the Python peers, in one run."""
    from ._io import write_json
    from .bench import run_suites, suites

    names = suite or list(suites())
    with console.status("benchmarking…"):
        try:
            reports = run_suites(names, quick=quick)
        except MptrackError as exc:
            err_console.print(f"[red]error:[/red] {exc}")
            raise typer.Exit(2) from None
    for rep in reports:
        rt = RichTable(title=f"{rep['suite']}: {rep['title']}", title_justify="left")
        for i, col in enumerate(rep["columns"]):
            rt.add_column(col, justify="left" if i == 0 else "right")
        for row in rep["rows"]:
            rt.add_row(*[_fmt(v) for v in row])
        console.print(rt)
        for note in rep.get("notes", []):
            console.print(f"[dim]{note}[/dim]")
    if json_out is not None:
        write_json(json_out, {"reports": reports})
        console.print(f"wrote {json_out}")


def main() -> None:  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
