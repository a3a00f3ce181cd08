"""The report of a paper reproduction: each table with our numbers beside the paper's, matching cells
green, differing cells red, differences explained by an erratum yellow with a link to it, uncounted
columns (the paper's inputs and labels repeated) plain, and the figures embedded."""

from __future__ import annotations

import base64
import re
from pathlib import Path

from .._core.validation import check_path
from ..errors import ParameterError
from ._page import esc, page, write_page

__all__ = ["write_reproduction_report", "explained_cells", "uncounted_columns"]


def _num(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return "—" if v is None else str(v)


def _check_table(table, name: str = "table", whole: bool = False) -> dict:
    """A results.json table (docs: RESULTS.md): a dict with a list of column names, its optional
    ``explained_by`` entries [row, column, erratum key] and ``uncounted`` column names; ``whole``: also
    its title, rows (lists as long as the columns) and the paper's rows (None, or as many rows)."""
    if not isinstance(table, dict) or not isinstance(table.get("columns"), list):
        raise ParameterError(f"{name}: expected a results.json table (a dict with a list of columns), "
                             f"got {table!r:.80}")
    if whole:
        width = len(table["columns"])
        rows, paper = table.get("rows"), table.get("paper")
        good = (isinstance(table.get("title"), str) and isinstance(rows, list)
                and all(isinstance(r, list) and len(r) == width for r in rows)
                and (paper is None or (isinstance(paper, list) and len(paper) == len(rows)
                                       and all(isinstance(r, list) and len(r) == width for r in paper))))
        if not good:
            raise ParameterError(f"{name}: expected a results.json table with a title, and rows (and the paper's "
                                 f"rows) of {width} cells, got {table!r:.80}")
    for entry in table.get("explained_by") or ():
        if not (isinstance(entry, (list, tuple)) and len(entry) == 3 and all(
                isinstance(i, int) and not isinstance(i, bool) for i in entry[:2])):
            raise ParameterError(f"{name}: expected explained_by entries [row, column, erratum key], got {entry!r:.80}")
    if not isinstance(table.get("uncounted") or [], (list, tuple)):
        raise ParameterError(f"{name}: expected uncounted as a list of column names, got {table['uncounted']!r:.80}")
    return table


def explained_cells(table: dict) -> dict[tuple[int, int], str]:
    """The explained cells of a results.json table.

    Parameters
    ----------
    table : dict
        A table of results.json (its ``explained_by``: [[row, col, key], ...]).

    Returns
    -------
    dict
        {(row, column): erratum key}.
    """
    table = _check_table(table)
    return {(int(e[0]), int(e[1])): str(e[2]) for e in table.get("explained_by") or ()}


_UNCOUNTED = "shown beside the paper, not counted: an input or label it printed, or a second version of counted cells"


def uncounted_columns(table: dict) -> set[int]:
    """The columns a results.json table shows but does not count (its "uncounted" column names).

    Parameters
    ----------
    table : dict
        A table of results.json.

    Returns
    -------
    set of int
        Column indices.
    """
    table = _check_table(table)
    names = set(map(str, table.get("uncounted") or ()))
    return {j for j, c in enumerate(table["columns"]) if c in names}


def _slug(text: str) -> str:
    """The anchor GitHub and most Markdown renderers give a heading."""
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


def _link(key: str, described: dict, errata: Path | None) -> str:
    """The erratum ``key`` of a differing cell and its description (results.json "errata"); the key
    links to its anchor in ``errata`` (docs/errata.md marks each erratum with ``<a id="KEY">``) when
    that file is known."""
    name = esc(key)
    if errata is not None:
        name = f"<a href='{esc(errata.resolve().as_uri())}#{esc(key)}'>{name}</a>"
    text = described.get(key)
    return f"erratum {name}" + (f": {esc(text)}" if text and text != key else "")


def _table_html(label: str, table: dict, described: dict, errata: Path | None) -> str:
    paper = table.get("paper")
    bad = {tuple(c) for c in table.get("mismatches", ())}
    why = explained_cells(table)
    shown_only = uncounted_columns(table)
    head = "".join(f"<th>{esc(c)}</th>" for c in table["columns"])
    if paper is not None:
        head = f"<th>{esc(table['columns'][0])}</th>" + "".join(
            f"<th>{esc(c)}<br><small>ours | paper</small></th>" for c in table["columns"][1:])
    rows, footnotes = [], []
    for i, row in enumerate(table["rows"]):
        cells = [f"<td>{esc(row[0])}</td>"]
        for j in range(1, len(row)):
            ours = esc(_num(row[j]))
            if paper is None or paper[i][j] is None:
                cells.append(f"<td>{ours}</td>")
                continue
            theirs = esc(_num(paper[i][j]))
            if j in shown_only:
                cells.append(f"<td title='{_UNCOUNTED}'>{ours}"
                             + ("" if ours == theirs else f" | {theirs}") + "</td>")
            elif (i, j) not in bad:
                cells.append(f"<td class='same' title='matches the paper'>{ours}"
                             + ("" if ours == theirs else f" | {theirs}") + "</td>")
            elif (i, j) in why:
                footnotes.append(f"<li id='{esc(_slug(label))}-{i}-{j}'>{esc(row[0])} / "
                                 f"{esc(table['columns'][j])}: {_link(why[(i, j)], described, errata)}</li>")
                cells.append(f"<td class='explained' title='differs; explained in docs/errata.md'>{ours} | "
                             f"{theirs} <a href='#{esc(_slug(label))}-{i}-{j}'>[{len(footnotes)}]</a></td>")
            else:
                cells.append(f"<td class='differs' title='differs from the paper; no erratum explains it'>"
                             f"{ours} | {theirs}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    html = (f"<h2 id='{esc(_slug(label))}'>{esc(label)}: {esc(table['title'])}</h2>"
            f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>")
    if table.get("tolerance"):
        tol = table["tolerance"]
        html += f"<p class='caption'>A number matches when |ours − paper| ≤ {tol['atol']:g} + {tol['rtol']:g}·|paper|.</p>"
    if table.get("notes"):
        html += f"<p class='note'>{esc(table['notes'])}</p>"
    if footnotes:
        html += "<ol class='errata'>" + "".join(footnotes) + "</ol>"
    return html


def write_reproduction_report(results: dict, path, *, figures_dir=None, errata=None,
                              counts: dict | None = None, title: str | None = None) -> Path:
    """Write the HTML page of a reproduction from its results.json content: each table beside the
    paper's, differences highlighted and linked to their erratum.

    Parameters
    ----------
    results : dict
        The reproduction's results.json content.
    path : str or path-like
        The HTML file.
    figures_dir : str or path-like, optional
        Where the figures named in ``results["figures"]`` are (embedded as PNG when found).
    errata : str or path-like, optional
        The path of docs/errata.md, the target of the links of explained differences.
    counts : dict, optional
        {"published", "matched", "explained", "unexplained"} for the heading line.
    title : str, optional
        The page's title (default: the reproduction's key).

    Returns
    -------
    pathlib.Path
    """
    if not isinstance(results, dict) or not isinstance(results.get("tables", {}), dict):
        raise ParameterError(f"results: expected the content of a results.json (a dict of tables ...), "
                             f"got {results!r:.80}")
    for table in results.get("tables", {}).values():
        _check_table(table, "results", whole=True)
    path = check_path("path", path)
    errata = check_path("errata", errata) if errata else None
    figures_dir = check_path("figures_dir", figures_dir) if figures_dir else None
    if counts is not None and not (isinstance(counts, dict) and {"published", "matched", "explained",
                                                                  "unexplained"} <= set(counts)):
        raise ParameterError(f"counts: expected {{'published', 'matched', 'explained', 'unexplained'}}, got "
                             f"{counts!r:.80}")
    if title is not None and not isinstance(title, str):
        raise ParameterError(f"title: expected a string or None, got {title!r:.80}")
    seed = results.get("seed")
    body = [f"<p class='note'>{esc(results.get('paper', ''))}"
            + ("" if seed is None else f"; random seed {esc(seed)}")
            + f"; mptrack {esc(results.get('mptrack_version', ''))}; {results.get('elapsed_s', 0):.1f} s</p>"]
    if counts:
        body.append(f"<p><strong>{counts['matched']} of {counts['published']} published numbers matched, "
                    f"{counts['explained']} differ for a documented reason (yellow, linked to the erratum), "
                    f"{counts['unexplained']} differ unexplained (red).</strong></p>")
    body.append("<p class='caption'>Cells: green = our number matches the paper's; yellow = differs, and "
                "docs/errata.md explains why; red = differs without an explanation; plain = the paper gives "
                "no number, or the column is not counted (the paper's inputs or labels repeated, or a second "
                "version of cells counted elsewhere).</p>")
    for label, table in results.get("tables", {}).items():
        body.append(_table_html(label, table, results.get("errata") or {}, errata))
    for name, file in results.get("figures", {}).items():
        png = Path(figures_dir or ".") / file
        if png.is_file() and png.suffix.lower() == ".png":
            data = base64.b64encode(png.read_bytes()).decode("ascii")
            body.append(f"<figure><img alt='{esc(name)}' src='data:image/png;base64,{data}'>"
                        f"<figcaption>{esc(name)}</figcaption></figure>")
        else:
            body.append(f"<p class='note'>{esc(name)}: {esc(file)} (not found beside the results)</p>")
    for note in results.get("notes", []):
        body.append(f"<p class='note'>note: {esc(note)}</p>")
    return write_page(path, page(title or str(results.get("key", "reproduction")), "".join(body)))
