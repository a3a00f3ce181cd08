"""The report of a tracking run: an interactive map (Leaflet, inlined) with every track in its own
colour and the raw fixes, rejected fixes, resets, gaps, truth and uncertainty ellipses as layers; a
list to show, hide and zoom to tracks; time plots of the selected track (speed, 1-sigma, NIS with its
chi-square band, error against truth); a data-quality section; and a sortable, paginated table of
every track.  Large tables are decimated (:mod:`._decimate`) so the page stays small and fast.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .._core.data_checks import check_frame, point_numbers
from .._core.finiteness import renamed
from .._core.validation import check_int, check_path
from ..errors import ParameterError, ShapeError
from ..runs import read_part
from ._decimate import DEFAULT_BUDGET
from ._page import esc, json_script, page, write_page
from ._payload import track_payload

__all__ = ["write_report", "report_points", "REPORT_COLUMNS", "PALETTE", "RAW_ON_BELOW",
           "LAYERS"]

#: The tracks' colours, in order (repeated beyond 16 tracks); the same list as in report.js.
PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22",
           "#ff7f0e", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd", "#31a354")
#: A point layer with more markers than this starts switched off (the page stays responsive).
RAW_ON_BELOW = 30_000
#: The columns of a point table that a report and its evaluation read (the input's other columns that
#: pass through a run are not needed).
REPORT_COLUMNS = ("track_id", "t", "method", "flag", "gap", "lat", "lon", "origin_lat", "origin_lon", "east_m",
                  "north_m", "vel_east_mps", "vel_north_mps", "var_east_m2", "cov_en_m2", "var_north_m2",
                  "ell_major_m", "ell_minor_m", "ell_azimuth_deg", "nis", "nis_dof", "meas_lat", "meas_lon",
                  "meas_east_m", "meas_north_m", "true_lat", "true_lon", "true_x", "true_y", "true_east_m",
                  "true_north_m", "error_m", "nees")


def report_points(sources) -> pd.DataFrame:
    """The point table a report needs from a run's point tables: :data:`REPORT_COLUMNS` only, in one
    frame.

    Files are memory-mapped and copied one at a time into the frame's columns, text as one Python object
    per distinct value, so the peak is about the frame itself.

    Parameters
    ----------
    sources : sequence of pyarrow.Table or path
        Tables, or part files (the chunks' parts :func:`mptrack.tracking.track_file` hands to
        ``on_points``, read by :func:`mptrack.runs.read_part`).

    Returns
    -------
    pandas.DataFrame

    Raises
    ------
    ShapeError
        The tables have different columns.
    DataError
        A file that is not a part.
    """
    import pyarrow as pa

    if isinstance(sources, (str, bytes, pd.DataFrame)) or not np.iterable(sources):
        raise ParameterError(f"sources: expected a list of pyarrow Tables or Arrow IPC files, got {sources!r:.80}")
    with renamed(path="sources"):
        tables = [src if isinstance(src, pa.Table) else read_part(src) for src in sources]
    if not tables:
        return pd.DataFrame({c: [] for c in ("track_id", "t", "flag")})
    names = [c for c in REPORT_COLUMNS if c in tables[0].column_names]
    for tb in tables[1:]:
        if [c for c in REPORT_COLUMNS if c in tb.column_names] != names:
            raise ShapeError(f"sources: the tables have different columns ({', '.join(names)} and "
                             f"{', '.join(c for c in REPORT_COLUMNS if c in tb.column_names)})")
    n = sum(tb.num_rows for tb in tables)
    columns = {}
    for name in names:
        typ = tables[0].schema.field(name).type
        nulls = any(tb.column(name).null_count for tb in tables)
        dtype = (object if pa.types.is_string(typ) or pa.types.is_large_string(typ) or pa.types.is_dictionary(typ)
                 else np.float64 if nulls and not pa.types.is_floating(typ) else typ.to_pandas_dtype())
        columns[name] = np.empty(n, dtype)
    start = 0
    for i in range(len(tables)):
        tb, tables[i] = tables[i], None  # unmapped once copied
        stop = start + tb.num_rows
        for name in names:
            col = tb.column(name)
            if columns[name].dtype == object:  # codes into the distinct values: one object per value
                enc = col.combine_chunks().dictionary_encode()
                values = np.array(enc.dictionary.to_pylist() + [None], dtype=object)
                codes = enc.indices.fill_null(len(values) - 1).to_numpy()
                columns[name][start:stop] = values[codes]
            else:
                columns[name][start:stop] = col.to_numpy()
        start = stop
    return pd.DataFrame(columns, copy=False)


#: The columns a report needs: a track, its times and flags, the 1-sigma of the position and the position
#: itself, in lat/lon or in local metres.
_NEEDED = ("track_id", "t", "flag", "var_east_m2", "var_north_m2")


def _check_report_inputs(tracks, path, summary, run, title, notes, budget) -> tuple:
    """write_report's arguments checked: (path, notes, budget)."""
    if isinstance(tracks, pd.DataFrame):
        position = ("lat", "lon") if {"lat", "lon"} <= set(tracks.columns) else ("east_m", "north_m")
        numbers = point_numbers(tracks, REPORT_COLUMNS)
    else:
        position, numbers = (), None
    check_frame("tracks", tracks, _NEEDED + position, numbers, empty=True)
    path = check_path("path", path)
    if not (isinstance(summary, dict) and isinstance(summary.get("overall"), dict)
            and isinstance(summary.get("tracks"), dict)):
        raise ParameterError("summary: expected the summary of mptrack.tracking.evaluate_tracks "
                             f"({{'overall': {{...}}, 'tracks': {{...}}}}), got {summary!r:.80}")
    if run is not None and not isinstance(run, dict):
        raise ParameterError(f"run: expected the summary of mptrack.tracking.track_file (a dict) or None, "
                             f"got {type(run).__name__}")
    if not isinstance(title, str):
        raise ParameterError(f"title: expected a string, got {title!r:.80}")
    if isinstance(notes, str) or not isinstance(notes, (list, tuple)) or not all(isinstance(n, str) for n in notes):
        raise ParameterError(f"notes: expected a list of strings, got {notes!r:.80}")
    return path, notes, check_int("budget", budget, minimum=1)


#: The map's layers besides the tracks' lines: what the legend calls each, its look in words (the caption)
#: and how it is drawn (Leaflet's marker or path options); the map, the legend's swatch and the caption
#: all take them from here, so they cannot disagree.
LAYERS = {
    "raw": {"label": "raw fixes", "look": "grey dots",
            "marker": {"radius": 2, "color": "#777777", "weight": 0, "fillColor": "#777777", "fillOpacity": 0.8}},
    "rejected": {"label": "fixes rejected by the NIS gate", "look": "orange rings",
                 "marker": {"radius": 4, "color": "#ff7f0e", "weight": 2, "fill": False}},
    "resets": {"label": "fixes that restarted the filter", "look": "purple rings",
               "marker": {"radius": 6, "color": "#6a3d9a", "weight": 2, "fill": False}},
    "gaps": {"label": "the first estimate after a gap", "look": "white dots ringed in black",
             "marker": {"radius": 5, "color": "#000000", "weight": 2, "fillColor": "#ffffff", "fillOpacity": 1}},
    "truth": {"label": "truth", "look": "dashed black line",
              "line": {"color": "#000000", "weight": 1.5, "dashArray": "5 5"}},
    "ellipses": {"label": "1-σ uncertainty ellipses", "look": "blue outlines",
                 "shape": "ellipse", "line": {"color": "#1f77b4", "weight": 1, "fillOpacity": 0.08}},
}


def _layer_text(kind: str) -> str:
    return f"{LAYERS[kind]['label']} ({LAYERS[kind]['look']})"



def _count(n: int) -> str:
    """A count with its thousands apart: 150 600 (a narrow no-break space)."""
    return f"{n:,}".replace(",", "\u202f")


def _plural(n: int, one: str, many: str | None = None) -> str:
    """"1 gap", "2 gaps", "1 fix", "12 fixes"."""
    return f"{_count(n)} {one if n == 1 else many or one + 's'}"


def _kinds(payload: dict) -> dict:
    """The point/line layers present in the data: {kind: {"count": drawn, "total": in the table,
    "text": what the layer's label says of them, "on": shown at load}}."""
    trs, totals = payload["tracks"], payload["totals"]
    drawn = {}
    if payload["has_meas"]:
        pairs = [(v, f) for t in trs if "my" in t for v, f in zip(t["my"], t["f"])]
        drawn["raw"] = sum(1 for v, f in pairs if v is not None and f != "o")
        drawn["rejected"] = sum(1 for v, f in pairs if v is not None and f == "o")
    drawn["resets"] = sum(t.get("f", "").count("r") for t in trs)
    drawn["gaps"] = sum(len(t.get("gap", ())) for t in trs)
    kinds = {}
    for kind, count in drawn.items():
        total = totals[kind]
        if total:
            kinds[kind] = {"count": count, "total": total, "on": count <= RAW_ON_BELOW,
                           "text": _count(total) if count == total else f"{_count(count)} of {_count(total)} drawn"}
    if payload["has_truth"]:
        n = sum(1 for t in trs if any(v is not None for v in t.get("ty", ())))
        kinds["truth"] = {"count": n, "total": n, "on": True, "text": f"{_count(n)} track{'s' if n != 1 else ''}"}
    if any("ell" in t for t in trs):
        kinds["ellipses"] = {"count": 1, "total": 1, "on": True, "text": "the selected track"}
    return kinds


#: How the caption names the layers thinned with the tracks (plural) or drawn in full (singular).
_THINNED = {"rejected": ("rejected fixes", "rejected fix"), "resets": ("resets", "reset"), "gaps": ("gaps", "gap")}


def _map_caption(payload: dict, kinds: dict, budget: int) -> str:
    n = len(payload["tracks"])
    text = (("The estimate of the track as a line" if n == 1 else f"The estimate of each of the {_count(n)} tracks "
                                                                  "as a line in its own colour")
            + (f" (the {len(PALETTE)} colours repeat)" if n > len(PALETTE) else "")
            + ("; a line breaks at a restart or a gap" if {"resets", "gaps"} & set(kinds) else "") + ".")
    on = [f"{_layer_text(k)}: {kinds[k]['text']}" for k in kinds if kinds[k]["on"]]
    off = [f"{_layer_text(k)}: {kinds[k]['text']}" for k in kinds if not kinds[k]["on"]]
    if on:
        text += " Also drawn: " + ", ".join(on) + "."
    if off:
        text += " Switched off at load (too many markers; tick them above the map): " + ", ".join(off) + "."
    if payload["decimated"]:
        text += (f" {_count(payload['drawn'])} of {_count(payload['points'])} points are drawn, a budget of about "
                 f"{_count(budget)} shared by every layer: every k-th point of each track")
        thinned = [_THINNED[k][0] for k in _THINNED if k in kinds and kinds[k]["count"] < kinds[k]["total"]]
        whole = [_THINNED[k][1] for k in _THINNED if k in kinds and kinds[k]["count"] == kinds[k]["total"]]
        if thinned:
            text += f"; {' and '.join(thinned)} are thinned alike (the counts above say how many are drawn)"
        if whole:
            text += f"; every {' and every '.join(whole)} is drawn"
        text += "."
    text += (" Background: OpenStreetMap tiles when the browser is online, otherwise a plain background; the scale "
             "bar (bottom left) is in metres." if payload["geo"] else
             " Axes: local east/north metres (the input had no latitude/longitude); the scale bar (bottom left) is "
             "in the same metres.")
    return text + " Click a track (on the map, in the list or in the table) to plot it over time."


def _quality(tracks: pd.DataFrame, summary: dict, run: dict | None) -> str:
    """The data-quality section: rows skipped by reason, records left out, the reader's notes,
    outliers/resets/gaps, and what a NIS far from its band means."""
    items = []
    read = (run or {}).get("read") or {}
    if read:
        skipped = read.get("rows_skipped", 0)
        items.append(f"{_count(read.get('rows_read', 0))} rows read from {esc(read.get('file', 'the input'))}; "
                     f"{_count(skipped)} skipped" + (" (the reasons below)" if skipped else ""))
        reasons = read.get("skipped_by_reason") or {}
        if reasons:
            items.append("rows skipped by reason:" + _count_table(reasons, "rows"))
        for ex in (read.get("examples") or [])[:5]:
            items.append(f"example: {esc(ex)}")
        notes = list(read.get("notes") or [])
        left_out = read.get("left_out") or {}
        if left_out:
            # each left-out record also has a note (where in the file, and why): listed under the table, once
            details = [n for n in notes if n.rstrip(". ").endswith("left out")]
            notes = [n for n in notes if n not in details]
            items.append("records left out (they are not fixes):" + _count_table(left_out, "records")
                         + ("<ul>" + "".join(f"<li>{esc(d)}</li>" for d in details) + "</ul>" if details else ""))
        for note in notes:  # rows sorted, duplicates dropped, units: each said once, by its note
            items.append(f"note: {esc(note)}")
    elif run is None:
        items.append("rows skipped while reading are not known to this report (it was written from a track "
                     "table; mptrack track --report lists them)")
    o = summary["overall"]
    gaps = int(tracks["gap"].sum()) if "gap" in tracks.columns else 0
    predicted = int((tracks["flag"] == "predicted").sum())
    restarts, resets = o.get("restarts", 0), o.get("resets", 0)
    outliers = o.get("outliers", 0)
    items.append(f"{_plural(outliers, 'fix', 'fixes')} rejected by the NIS gate, {_plural(restarts, 'restart')} of "
                 f"the filter ({_plural(resets, 'fix', 'fixes')} flagged reset), {_plural(gaps, 'gap')}, "
                 f"{_plural(predicted, 'point')} predicted without a fix")
    nis = summary.get("nis") or {}
    if nis.get("sentence") and o.get("nis_fixes"):
        why = {"below": "; far below: the filter assumes more noise than the data show",
               "above": "; far above: the data are noisier or the motion more agile than the filter assumes"}
        outside, judged = nis.get("tracks_outside_band"), nis.get("tracks_judged") or 0
        inside = o.get("nis_in_95")
        items.append(esc(nis["sentence"]) + why.get(nis.get("far"), "")
                     + (f"; {outside} of {judged} tracks outside their own band" if judged > 1 else "")
                     + (f"; {100 * inside:.1f} % of these fixes inside their own 95 % χ² interval"
                        if inside is not None and np.isfinite(inside) else ""))
    for text in ((run or {}).get("nis") or summary.get("nis") or {}).get("advice") or []:
        items.append(f"<strong>advice:</strong> {esc(text)}")
    return "<ul class='quality'>" + "".join(f"<li>{i}</li>" for i in items) + "</ul>"


def _count_table(counts: dict, what: str) -> str:
    """A table of counts by reason, the largest first."""
    rows = "".join(f"<tr><td>{esc(r)}</td><td>{_count(c)}</td></tr>"
                   for r, c in sorted(counts.items(), key=lambda kv: -kv[1]))
    return (f"<table class='reasons'><thead><tr><th>reason</th><th>{what}</th></tr></thead>"
            f"<tbody>{rows}</tbody></table>")


#: The columns of the table of every track, in order (those the evaluation has).
TABLE_COLUMNS = ("points", "matched_points", "outliers", "restarts", "rmse_m", "mean_error_m", "cdf50_m", "cdf67_m",
                 "cdf95_m", "mean_nees", "nees_in_95", "mean_nis", "nis_consistent", "nis_in_95")


def _summary_rows(summary: dict) -> dict:
    per = summary["tracks"]
    cols = [c for c in TABLE_COLUMNS if any(c in r for r in [summary["overall"], *per.values()])]
    return {"columns": ["track", *cols],
            "overall": ["all", *[summary["overall"].get(c) for c in cols]],
            "rows": [[str(k), *[r.get(c) for c in cols]] for k, r in per.items()]}


def write_report(tracks: pd.DataFrame, path, *, summary: dict, run: dict | None = None,
                 title: str = "mptrack report", notes: list[str] | tuple[str, ...] = (),
                 budget: int = DEFAULT_BUDGET) -> Path:
    """Write the HTML report of a tracking run atomically (one file, works offline).

    Parameters
    ----------
    tracks : pandas.DataFrame
        The point table of ``mptrack track`` (:func:`mptrack.io.read_output`), with the error and truth
        columns of :func:`mptrack.tracking.evaluate_tracks` when evaluated.
    path : str or path-like
        The HTML file.
    summary : dict
        The evaluation of ``tracks`` (the first value :func:`mptrack.tracking.evaluate_tracks` returns):
        every track is in the page's table; its "nis" part gives the mean NIS sentence, verdict and advice.
    run : dict, optional
        The summary :func:`mptrack.tracking.track_file` returns, for the data-quality section (rows
        skipped by reason, records left out, the reader's notes, NIS advice).
    title : str, optional
    notes : sequence of str, optional
        Further notes printed on the page.
    budget : int, optional
        About how many points the map and plots draw in all (larger tables are decimated, every event
        kept).

    Returns
    -------
    pathlib.Path
    """
    path, notes, budget = _check_report_inputs(tracks, path, summary, run, title, notes, budget)
    payload = track_payload(tracks, budget=budget)
    kinds = _kinds(payload)
    methods = ", ".join(map(str, pd.unique(tracks["method"]))) if "method" in tracks.columns else "?"
    n = len(payload["tracks"])
    body = [f"<p class='note'>{_count(n)} track{'s' if n != 1 else ''}, {_count(len(tracks))} points; method: "
            f"{esc(methods)}" + (f"; drawn: {_count(payload['drawn'])} points (decimated)" if payload["decimated"]
                                 else "") + "</p>"]
    body += [f"<p class='note'>{esc(note)}</p>" for note in notes]
    body.append("<noscript><p><strong>This report needs JavaScript for its map, plots and table.</strong></p>"
                "</noscript>")
    body.append("<section id='map-section'><h2>Map</h2><div id='layers'></div><div class='layout'><aside>"
                "<input id='track-filter' type='search' placeholder='filter tracks'><div>"
                "<button id='show-all' type='button'>show all</button> <button id='hide-all' type='button'>"
                "hide all</button></div><ul id='track-list'></ul></aside><div id='map'></div></div>"
                f"<p class='caption' id='map-caption'>{esc(_map_caption(payload, kinds, budget))}</p></section>")
    body.append("<section id='plots-section'><h2>Over time: track <span id='plots-track'></span></h2>"
                "<div id='plots'></div><p class='caption' id='plots-caption'></p></section>")
    body.append(f"<section id='quality-section'><h2>Data quality</h2>{_quality(tracks, summary, run)}</section>")
    body.append("<section id='table-section'><h2>All tracks</h2><p class='caption'>One row per track (the first "
                "row: all tracks together). Click a heading to sort, a track to show it on the map.</p>"
                "<input id='table-filter' type='search' placeholder='filter tracks'><div class='pager'>"
                "<button id='prev-page' type='button'>◀</button> <span id='page-info'></span> "
                "<button id='next-page' type='button'>▶</button></div><table id='summary'></table></section>")
    body.append(json_script("mptrack-data", {"payload": payload, "kinds": kinds, "layers": LAYERS,
                                             "summary": _summary_rows(summary)}))
    return write_page(path, page(title, "".join(body), scripts=("leaflet.js", "report.js"),
                                 styles=("leaflet.css",)))
