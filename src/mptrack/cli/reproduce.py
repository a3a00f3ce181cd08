"""``mptrack reproduce``: a paper's tables beside the published numbers, and the counts of what
matches, what differs for a documented reason (docs/errata.md) and what differs unexplained."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape
from rich.table import Table as RichTable

from ..errors import MptrackError
from ._common import JSON, QUIET, VERBOSE, echo, err, fail, fmt, interrupted, note, out, paper_names, print_json, \
    progress, reject, reject_given, short_paper

__all__ = ["reproduce", "cell_counts", "summary_line"]

ERRATA = "docs/errata.md"


def _explained(table: dict) -> dict:
    from ..report import explained_cells

    return explained_cells(table)


def _named(value):
    """results.json content with every text (table labels included) naming papers by author and year."""
    if isinstance(value, str):
        return paper_names(value)
    if isinstance(value, dict):
        return {_named(k): _named(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_named(v) for v in value]
    return value


def _uncounted(table: dict) -> set[int]:
    from ..report import uncounted_columns

    return uncounted_columns(table)


def cell_counts(results: dict) -> dict:
    """{"published", "matched", "explained", "unexplained"} over the published cells of a results.json
    that we compute (not its "uncounted" inputs and labels): its "comparison" when it has one, else counted
    from each table's paper, mismatches and explained_by."""
    c = results.get("comparison")
    if c:
        return {"published": c["compared"], "matched": c["matched"], "explained": c["differing_explained"],
                "unexplained": c["differing_unexplained"]}
    published = differing = explained = 0
    for table in results.get("tables", {}).values():
        paper = table.get("paper")
        if paper is None:
            continue
        bad = {tuple(c) for c in table.get("mismatches", ())}
        skip = _uncounted(table) | {0}
        published += sum(1 for row in paper for j, v in enumerate(row) if v is not None and j not in skip)
        differing += len(bad)
        explained += len(bad & set(_explained(table)))
    return {"published": published, "matched": published - differing, "explained": explained,
            "unexplained": differing - explained}


def summary_line(key: str, results: dict, path: Path) -> str:
    """The last line of a paper's reproduction."""
    c = cell_counts(results)
    line = (f"{key} ({short_paper(results.get('paper', key))}): {c['matched']}/{c['published']} "
            f"published numbers matched, {c['explained']} differ for a documented reason, {c['unexplained']} "
            f"differ unexplained (see {ERRATA})")
    return line + f"; {len(results.get('figures', {}))} figures, {results.get('elapsed_s', 0):.1f} s → {path}"


def _print_tables(results: dict, verbose: bool) -> None:
    """Each table with our numbers and the paper's side by side; differing cells flagged."""
    out.print(f"[bold]{escape(results['key'])}[/bold] — {escape(paper_names(results['paper']))}")
    for label, table in results["tables"].items():
        bad = {tuple(c) for c in table.get("mismatches", ())}
        why = _explained(table)
        paper = table.get("paper")
        shown_only = _uncounted(table)
        rt = RichTable(title=f"{label}: {paper_names(table['title'])}", title_justify="left")
        rt.add_column(table["columns"][0])
        for col in table["columns"][1:]:
            rt.add_column(f"{col}" + (" (ours | paper)" if paper is not None else ""), justify="right")
        for i, row in enumerate(table["rows"]):
            cells = [str(row[0])]
            for j in range(1, len(row)):
                ours = fmt(row[j])
                if paper is None or paper[i][j] is None or (j in shown_only and row[j] == paper[i][j]):
                    cells.append(ours)  # the paper's input or label repeated: show it once, not counted
                elif j in shown_only:
                    cells.append(f"{ours} | {fmt(paper[i][j])}")  # shown beside the paper's, not counted
                elif not isinstance(row[j], (int, float)) and (i, j) not in bad:
                    cells.append(ours)  # identical computed text (a formula): show it once
                else:
                    mark = ("[yellow]≠*[/yellow]" if (i, j) in why else "[red]≠[/red]") \
                        if (i, j) in bad else "[green]=[/green]"
                    cells.append(f"{ours} {mark} {fmt(paper[i][j])}")
            rt.add_row(*cells)
        out.print(rt)
        if table.get("notes"):
            out.print(paper_names(table["notes"]), style="dim", markup=False, highlight=False)
        if verbose:
            for i, j in sorted(bad):
                entry = why.get((i, j))
                echo(f"  {label} {table['rows'][i][0]} / {table['columns'][j]}: "
                     + (f"explained by {ERRATA}#{entry}: {(results.get('errata') or {}).get(entry, entry)}"
                        if entry is not None else "unexplained"))
    for name, path in results.get("figures", {}).items():
        echo(f"{name}: {path}")
    for text in results.get("notes", []):
        note(paper_names(text))


def reproduce(
    ctx: typer.Context,
    key: Optional[str] = typer.Argument(None, help="Reproduction key (see --list), or 'all'."),
    out_root: Path = typer.Option(Path("mptrack-results"), "--out", "-o", help="Output root; results go to "
                                                                               "OUT/KEY/."),
    seed: Optional[int] = typer.Option(None, help="Override the reproduction's default seed."),
    list_: bool = typer.Option(False, "--list", help="List the reproduction keys and exit."),
    quick: bool = typer.Option(False, help="Reduced Monte-Carlo sizes (for smoke tests)."),
    resume: bool = typer.Option(True, help="Reuse finished parts cached under OUT/KEY/.cache."),
    report: bool = typer.Option(False, "--report", help="Also write OUT/KEY/report.html: each table beside the "
                                                        "paper's, differences highlighted and linked to their "
                                                        "erratum."),
    quiet: bool = QUIET,
    verbose: bool = VERBOSE,
    json_out: bool = JSON,
) -> None:
    """Reproduce a paper's tables and figures, side by side with the published numbers."""
    from ..experiments import experiments, run_experiment

    reg = experiments()
    if list_ or key is None:
        if list_ and key is not None:
            reject("--list", f"lists the reproductions and runs none: leave out --list to run {key}")
        reject_given(ctx, ["out_root", "seed", "quick", "resume", "report"],
                     "applies to a reproduction run, not to the list (give a KEY or 'all')")
        if json_out:
            print_json({k: {"paper": paper_names(e.paper), "description": paper_names(e.description)}
                        for k, e in reg.items()})
            return
        for k, exp in reg.items():
            out.print(f"[bold]{k}[/bold]  {escape(paper_names(exp.paper))}"
                      + ("" if quiet else f"\n    {escape(paper_names(exp.description))}"), highlight=False)
        return
    todo = list(reg) if key == "all" else [key]
    done = {}
    try:
        for k in todo:
            with progress(quiet or json_out) as bar:
                rep = run_experiment(k, out_root, seed=seed, quick=quick, resume=resume, progress=bar)
            path = out_root / k / "results.json"
            results = _named(json.loads(path.read_text()) if path.exists() else rep.to_json())
            if report:
                from ..report import write_reproduction_report

                results["report"] = str(write_reproduction_report(results, out_root / k / "report.html",
                                                                  figures_dir=out_root / k,
                                                                  errata=_errata_file(),
                                                                  counts=cell_counts(results),
                                                                  title=f"{k}: {short_paper(results['paper'])}"))
            done[k] = results
            if json_out:
                continue
            if quiet:
                continue
            _print_tables(results, verbose)
            echo(summary_line(k, results, path) + (f"; report {results['report']}" if report else ""))
    except KeyboardInterrupt:
        interrupted(f"finished: {', '.join(done) or 'none'} (finished parts are cached for --resume)")
    except (MptrackError, OSError) as exc:
        fail(exc)
    if json_out:
        print_json({k: {**r, "counts": cell_counts(r)} for k, r in done.items()})
        return
    unexplained = [k for k, r in done.items() if cell_counts(r)["unexplained"]]
    if not quiet and (len(done) > 1 or unexplained):
        err.print(f"differences without a documented reason in: {', '.join(unexplained)} (see the tables and "
                  f"{ERRATA})" if unexplained else f"every difference from the papers is documented in {ERRATA}",
                  highlight=False, markup=False, soft_wrap=True)


def _errata_file() -> Path | None:
    """docs/errata.md of the source tree this mptrack runs from, if there is one (a link target)."""
    here = Path(__file__).resolve().parents[3] / "docs" / "errata.md"
    return here if here.is_file() else None
