"""``mptrack bench``: the speed suites, each measured against an anchor in the same run."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table as RichTable

from ..errors import MptrackError
from ._common import JSON, QUIET, VERBOSE, echo, fail, interrupted, out, paper_names, print_json, progress, \
    reject_given

__all__ = ["bench", "figure"]

#: Significant figures of a measured figure in a table: timings repeat to a few per cent at best
#: (the JSON of --save / --json keeps every digit).
FIGURES = 3


def figure(v) -> str:
    """A table cell: a float to FIGURES significant figures (0.0123, 1.23, 12.3, 1.2e-05, 2.41e+08;
    from 1 to 10^5 every digit before the point: 1235); other values as text, None as a dash."""
    if isinstance(v, bool) or not isinstance(v, float):
        return "—" if v is None else str(v)
    if v != v or v in (float("inf"), float("-inf")):
        return str(v)
    if v == 0.0:
        return "0"
    size = abs(v)
    if 1.0 <= size < 1e5:          # whole numbers keep their digits: 1235, not 1.24e+03
        return f"{v:.{max(0, FIGURES - len(str(int(size))))}f}"
    return f"{v:#.{FIGURES}g}"   # "#": trailing zeros are significant (0.180, not 0.18)


def bench(
    ctx: typer.Context,
    quick: bool = typer.Option(False, help="Small sizes, a few seconds."),
    suite: Optional[list[str]] = typer.Option(None, help="Run only these suites (repeatable)."),
    save: Optional[Path] = typer.Option(None, "--save", help="Also write the results as JSON to this file."),
    db: Optional[str] = typer.Option(None, "--db", help="The serve suite on this PostgreSQL database "
                                                        "(postgresql://...; it works in schemas of its own and drops "
                                                        "them): workers 1 vs 2, bulk COPY."),
    list_: bool = typer.Option(False, "--list", help="List the suites and exit."),
    quiet: bool = QUIET,
    verbose: bool = VERBOSE,
    json_out: bool = JSON,
) -> None:
    """Benchmark mptrack against a memory-copy baseline and the Python peers, in one run."""
    from .._core.files import write_json
    from ..bench import run_suites, suites

    if list_:
        reject_given(ctx, ["quick", "suite", "save"], "does not apply with --list (it lists the suites and runs none)")
        if json_out:
            print_json(list(suites()))
            return
        for name in suites():
            echo(name)
        return
    names = suite or list(suites())
    reports = []
    try:
        with progress(quiet or json_out) as bar:
            for name in names:
                with bar.task(f"bench {name}"):
                    reports += run_suites([name], quick=quick, db=db)
        if save is not None:
            write_json(save, {"reports": reports})
    except KeyboardInterrupt:
        interrupted("nothing was written")
    except (MptrackError, OSError) as exc:
        fail(exc)
    if json_out:
        print_json({"reports": reports})
        return
    if quiet:
        return
    for rep in reports:
        rt = RichTable(title=paper_names(f"{rep['suite']}: {rep['title']}"), title_justify="left")
        for i, col in enumerate(rep["columns"]):
            rt.add_column(col, justify="left" if i == 0 else "right")
        for row in rep["rows"]:
            rt.add_row(*[paper_names(figure(v)) for v in row])
        out.print(rt)
        for text in rep.get("notes", []):
            out.print(paper_names(text), style="dim", highlight=False, markup=False)
    if save is not None:
        echo(f"wrote {save}")
