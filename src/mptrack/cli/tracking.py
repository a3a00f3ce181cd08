"""``mptrack track``, ``mptrack simulate`` and ``mptrack evaluate``: real data in, tracks out
(docs/tracking.md).

Errors in the input exit with status 2 and a message naming file, row and column; nothing is
written then.  An output that cannot be written (another run holds its lock, a directory, a
read-only directory, a full disk, a file that vanished) exits with status 2 and one line naming the
path and the cause; Ctrl-C exits with status 130 and one line.  When ``track`` stops that way after
finishing some chunks, the line says where they were kept and gives the command that resumes the run.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import List, NamedTuple, Optional

import typer
from rich.markup import escape
from rich.table import Table as RichTable

from ..errors import MptrackError
from ._common import JSON, QUIET, VERBOSE, check_outputs, command_line, echo, err, fail, flags_named, \
    interrupted, note, out, print_json, progress, reject_given

__all__ = ["track", "simulate", "evaluate"]


def _kept(out: Path) -> str:
    """What a stopped ``track`` run kept for ``--resume`` ("" when nothing)."""
    from ..runs import PartStore

    try:
        store = PartStore(out)
    except MptrackError:
        return ""
    n = len(store.parts("tracks"))
    if not n:
        return ""
    return (f"; {n} finished chunk{'s' if n != 1 else ''} kept in {store.dir}; "
            f"resume with: {command_line(resume=True)}")


class _Reading(NamedTuple):
    columns: typer.models.OptionInfo
    time_unit: typer.models.OptionInfo
    time_format: typer.models.OptionInfo
    coord_unit: typer.models.OptionInfo
    timezone: typer.models.OptionInfo


def _reading_options(what: str) -> _Reading:
    """The options that say how a position-fix file is read (its column names and units), defined once
    for ``track``'s input, ``simulate --along`` and ``evaluate --truth``; ``what`` names the file in
    the help."""
    return _Reading(
        typer.Option(None, "--columns", help=f"Which column of {what} is which where the names are not "
                                             "recognised: time=ts,lat=Latitude,lon=Lng,track_id=device,"
                                             "accuracy_m=acc (swapped columns: lat=lon,lon=lat)."),
        typer.Option("auto", "--time-unit", help=f"Unit of numeric time stamps of {what}: auto (by magnitude), "
                                                 "s, ms, us or ns."),
        typer.Option(None, "--time-format", help=f"Layout of text time stamps of {what} that are not ISO 8601, "
                                                 "e.g. '%d/%m/%Y %H:%M:%S'."),
        typer.Option("auto", "--coord-unit", help=f"Unit of lat/lon of {what}: auto, deg, deg-e7 or deg-e6 "
                                                  "(integer degrees x 10^7 / 10^6) or rad."),
        typer.Option(None, "--timezone", help=f"Time zone of the local time stamps of {what} when it is a "
                                              "G-NetTrack Pro log, e.g. Europe/Brussels (default: read as UTC)."))


_TRACK_READING = _reading_options("the input")
_ALONG_READING = _reading_options("the --along file")
_TRUTH_READING = _reading_options("the --truth file")


def _read_options(ctx, columns, time_unit, time_format, coord_unit, timezone, *, file="", option: str = "",
                  **more):
    """The :class:`mptrack.io.ReadOptions` of the reading options (errors name the option); given without
    the file they apply to (``file`` None, named by ``option``) they are refused."""
    from ..io import ReadOptions

    if file is None:
        reject_given(ctx, _Reading._fields, f"applies to the file read with {option}")
    with flags_named(ctx):
        return ReadOptions(columns=columns or (), time_unit=time_unit, time_format=time_format,
                           coord_unit=coord_unit, timezone=timezone, **more)


def _skipped(read: dict, verbose: bool) -> None:
    for text in read.get("notes", ()):
        note(text)
    if read.get("rows_skipped"):
        note(f"{read['rows_skipped']} of {read['rows_read']} rows of {read['file']}:", "skipped")
        for reason, count in read["skipped_by_reason"].items():
            err.print(escape(f"  {count} × {reason}"), highlight=False, soft_wrap=True)
        for example in read.get("examples", ()) if verbose else ():
            err.print(escape(f"  e.g. {example}"), highlight=False, soft_wrap=True)


#: The columns of ``evaluate``'s table, numbers to 4 significant digits (``--json`` has every digit).
_TERMINAL_COLUMNS = ("points", "outliers", "restarts", "rmse_m", "cdf95_m", "mean_nees", "nees_in_95", "mean_nis",
                     "nis_in_95")


def _summary_table(summary: dict, title: str, rows_max: int | None) -> RichTable:
    tracks = list(summary["tracks"].items())
    rows = {"all": summary["overall"], **dict(tracks[:rows_max] if rows_max else tracks)}
    cols = [c for c in _TERMINAL_COLUMNS if any(c in r for r in rows.values())]
    rt = RichTable(title=title + (f" (first {rows_max} of {len(tracks)} tracks; -v for all, --json for "
                                  "every number)" if rows_max and len(tracks) > rows_max else ""),
                   title_justify="left")
    rt.add_column("track")
    for c in cols:
        rt.add_column(c, justify="right")
    for k, r in rows.items():
        rt.add_row(k, *[f"{r[c]:.4g}" if isinstance(r.get(c), float) else str(r.get(c, "")) for c in cols])
    return rt




def _default_out(input) -> Path:
    """``--out`` when not given: INPUT's name with ``.tracks.parquet`` beside it (a directory's name beside
    the directory); several files: their common directory's, beside it (not inside, where a later run on
    the directory would read it)."""
    import os

    if isinstance(input, list):
        input = Path(os.path.commonpath([os.path.abspath(p.parent) for p in input]))
    name = input.name.split(".")[0] if not input.is_dir() else input.name
    return input.parent / f"{name}.tracks.parquet"


def track(
    ctx: typer.Context,
    inputs: List[Path] = typer.Argument(..., metavar="INPUT...", help="Position fixes: CSV (any delimiter), "
                                        "Parquet (a file or a directory), GPX, TCX, FIT, NMEA 0183 or GeoJSON; or, "
                                        "with --cells, a cellular measurement log (CSV/Parquet). Several files, a "
                                        "glob ('rides/*.gpx') or a directory of such files are one input, each "
                                        "file's tracks kept apart (ids FILE/TRACK)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Result: .parquet, .csv, .geojson, .gpx or "
                                                                 ".geoparquet (written atomically; the input's "
                                                                 "other columns pass through). Default: "
                                                                 "INPUT.tracks.parquet beside the input."),
    cells: Optional[Path] = typer.Option(None, "--cells", help="Cell table (OpenCelliD layout): track cellular "
                                                               "measurements with --method."),
    method: Optional[str] = typer.Option(None, help="With --cells: locate (default: each scan placed as the "
                                                    "server's /v1/geolocate places a request, co-sited cells one "
                                                    "site, the covariance the posterior's), or a range filter over "
                                                    "time (Bouzera et al. 2017): ekf, fekf or fcs."),
    motion: Optional[str] = typer.Option(None, help="With --cells and a range filter: the motion model, "
                                                    "random-walk (default) or cv."),
    path_loss: Optional[str] = typer.Option(None, "--path-loss", help="With --cells and a range filter: the "
                                            "path-loss model that turns RSS into ranges: cost231-wi-nlos (default), "
                                            "cost231-wi-los, cost231-hata, okumura-hata or free-space."),
    range_sigma: Optional[float] = typer.Option(None, "--range-sigma", help="With --cells: the range noise "
                                                "(1-sigma, m). Default 471 m (Bouzera et al. 2017's "
                                                "R0 = 0.222 km^2)."),
    model: Optional[str] = typer.Option(None, help="Position fixes: the motion model, cv (default) or ca."),
    filter: Optional[str] = typer.Option(None, "--filter", help="Position fixes: kf (default; gated, irregular "
                                                                "times) or a linear filter name (lf, sskf, ...) "
                                                                "on a regular grid."),
    smooth: bool = typer.Option(False, "--smooth", help="Position fixes: add an RTS smoothing pass."),
    q: Optional[float] = typer.Option(None, help="Position fixes: process-noise density (m^2/s^3 for cv). "
                                                 "Default: estimated from each track."),
    sigma: Optional[float] = typer.Option(None, help="Position fixes: fix noise (1-sigma per axis, m) where the "
                                                     "input has no accuracy_m. Default: estimated from each track "
                                                     "(with accuracy_m: a scale factor on it)."),
    noise: Optional[str] = typer.Option(None, help="Position fixes: track (default) estimates the noise per track "
                                                   "(short tracks share one estimate); file: one estimate for the "
                                                   "whole input."),
    gate: Optional[float] = typer.Option(None, help="Position fixes: NIS gate probability (chi-square; default "
                                                    "0.999); 1 disables gating."),
    max_gap: Optional[float] = typer.Option(None, "--max-gap", help="Position fixes: a gap longer than this many "
                                                                    "seconds starts a new segment (the filter "
                                                                    "starts again at the fix after it). Default "
                                                                    "600; inf: never."),
    report: Optional[Path] = typer.Option(None, "--report", help="Also write a self-contained HTML report (an "
                                                                 "interactive map, time plots, data quality and "
                                                                 "a table of every track)."),
    track_summary: Optional[Path] = typer.Option(None, "--track-summary", help="Also write the per-track table "
                                                 "(noise estimates with standard errors, counts, NIS): "
                                                 ".parquet or .csv."),
    on_error: str = typer.Option("raise", "--on-error", help="raise: stop at the first bad row; skip: drop bad "
                                                             "rows, count and report them."),
    max_skip: str = typer.Option("1%", "--max-skip", help="With --on-error skip: fail (nothing written) when more "
                                                          "rows than this are dropped: a percentage of the rows "
                                                          "read or a count."),
    columns: Optional[str] = _TRACK_READING.columns,
    time_unit: str = _TRACK_READING.time_unit,
    time_format: Optional[str] = _TRACK_READING.time_format,
    coord_unit: str = _TRACK_READING.coord_unit,
    timezone: Optional[str] = _TRACK_READING.timezone,
    resume: bool = typer.Option(False, "--resume", help="Keep the work of an interrupted run of the same input "
                                                        "and options."),
    executor: str = typer.Option("serial", help="serial, processes or dask: who runs the chunks (the output "
                                                "is the same)."),
    workers: Optional[int] = typer.Option(None, "--workers", help="Processes / Dask workers (default: cores)."),
    chunk_rows: int = typer.Option(200_000, "--chunk-rows", help="Rows of whole tracks per chunk (memory)."),
    quiet: bool = QUIET,
    verbose: bool = VERBOSE,
    json_out: bool = JSON,
) -> None:
    """Track position fixes or cellular measurements; write estimates, covariances, NIS and flags.

    With no --sigma/--q the fix noise and the process noise are estimated from each track."""
    from ..tracking import CELL_ONLY, FIX_ONLY

    given = {"model": model, "filter": filter, "smooth": smooth or None, "q": q, "sigma_m": sigma, "noise": noise,
             "gate_probability": gate, "max_gap_s": max_gap, "method": method, "motion": motion,
             "path_loss": path_loss}
    reject_given(ctx, FIX_ONLY if cells is not None else CELL_ONLY,
                 "applies to position fixes, not to cellular measurements (--cells)" if cells is not None
                 else "applies to cellular measurements only: give the cell table with --cells")
    if executor == "serial":
        reject_given(ctx, ["max_workers"], "applies to --executor processes or dask")
    if on_error != "skip":
        reject_given(ctx, ["max_skip"], "applies to --on-error skip")
    from ..io import input_name, input_paths, resolve_input

    try:
        input = resolve_input(inputs, "INPUT")
    except MptrackError as exc:
        fail(exc)
    out = out or _default_out(input)
    from .._core.validation import check_positive
    from ..runs import output_lock
    from ..tracking import TrackOptions, track_file, write_track_report

    kept, summary, points = "", None, []
    try:
        check_outputs(*input_paths(input), cells, out=out, track_summary=track_summary, report=report)
        values = {k: v for k, v in given.items() if v is not None}
        if "gate_probability" in values and values["gate_probability"] >= 1:
            values["gate_probability"] = None
        with flags_named(ctx):
            if range_sigma is not None:  # the option is a standard deviation in m, the setting a variance in km^2
                values["r_km2"] = (check_positive("range_sigma", range_sigma) / 1e3) ** 2
            options = TrackOptions(**values)
        read = _read_options(ctx, columns, time_unit, time_format, coord_unit, timezone, max_skip=max_skip)
        # track_file locks out and track_summary for its run; the report, written here, is locked here
        with output_lock(report, note=command_line()):
            try:
                with progress(quiet or json_out) as bar, flags_named(ctx):
                    summary = track_file(input, out, cells=cells, options=options, on_error=on_error,
                                         read=read, resume=resume, executor=executor, max_workers=workers,
                                         chunk_rows=chunk_rows, track_summary=track_summary, progress=bar,
                                         on_points=None if report is None else _keep_points(points),
                                         note=command_line())
                    if report is not None:
                        with bar.task("report"):
                            write_track_report(points.pop(), report, run=summary,
                                               title=f"mptrack track {input_name(input)}")
                        summary["report"] = str(report)
            except (OSError, KeyboardInterrupt):
                kept = _kept(out)  # the parts the stopped run kept (it released the lock of out)
                raise
    except KeyboardInterrupt:
        interrupted(f"{out} is complete, the report was not written" if summary is not None
                    else kept.removeprefix("; ") or "nothing was kept")
    except (MptrackError, OSError) as exc:
        fail(exc, kept)
    drop = CELL_ONLY if cells is None else FIX_ONLY
    summary["options"] = {k: v for k, v in summary.get("options", {}).items() if k not in drop}
    if json_out:
        print_json(summary)
        return
    if quiet:
        return
    _skipped(summary["read"], verbose)
    restarts = summary.get("restarts", 0)
    echo(f"{summary['tracks']} tracks ({summary['tracks_resumed']} resumed), {summary['points_written']} "
         f"points, {summary['outliers_rejected']} outliers rejected"
         + (f", {restarts} restart{'s' if restarts != 1 else ''}" if cells is None else "") + f" → {out}"
         + (f"; report {report}" if report else "") + (f"; tracks {track_summary}" if track_summary else ""))
    if 1 < len(summary.get("track_noise", ())) <= (30 if verbose else 10):
        out_print(_noise_table(summary["track_noise"]))
    for line in _noise_lines(summary, track_summary):
        echo(line)
    _nis_line(summary.get("nis") or {})
    _advise(summary)


def _nis_line(nis: dict) -> None:
    """The mean NIS of a run or an evaluation (its summary's sentence, :func:`mptrack.tracking.nis_sentence`:
    the words of the report and of the other command), with how many tracks lie outside their own band."""
    if not nis.get("nis_fixes"):
        return
    outside, judged = nis.get("tracks_outside_band"), nis.get("tracks_judged")
    echo(nis["sentence"] + (f"; {outside} of {judged} tracks outside their own band"
                            if outside is not None and judged and judged > 1 else ""))


def out_print(renderable) -> None:
    out.print(renderable)


def _keep_points(kept: list):
    """``track_file``'s ``on_points``: the columns of the run's points a report needs, appended to ``kept``
    (read from the run's parts whatever the output format: a GeoJSON or GPX output is not read back).
    Arrow's memory pool first gives back what writing the output left unused (about 0.2 GB for 10^6
    points), so the report starts from what the tracking really holds."""
    import pyarrow as pa

    from ..report import report_points

    def keep(tables) -> None:
        pa.default_memory_pool().release_unused()
        kept.append(report_points(tables))
    return keep


def _noise_table(rows: list[dict]) -> RichTable:
    """The noise of each track (a few tracks): estimate ± standard error and where it came from."""
    rt = RichTable(title="noise per track", title_justify="left")
    for col in ("track", "fixes", "sigma (m)", "q", "from", "mean NIS"):
        rt.add_column(col, justify="left" if col in ("track", "from") else "right")

    def pm(v, se):
        return f"{v:.3g}" + (f" ± {se:.2g}" if se is not None else "")

    for r in rows:
        src = r["sigma_source"] if r["sigma_source"] == r["q_source"] else f"{r['sigma_source']}/{r['q_source']}"
        nis = "" if r["mean_nis"] is None else f"{r['mean_nis']:.4g}"
        rt.add_row(str(r["track_id"]), str(r["fixes"]), pm(r["sigma_m"], r["sigma_se_m"]), pm(r["q"], r["q_se"]),
                   src, nis)
    return rt


def _noise_lines(summary: dict, track_summary) -> list[str]:
    """The noise the run used, in a sentence (one track) or as medians and ranges (many)."""
    noise = summary.get("noise")
    lines = []
    if noise:
        src = ", ".join(f"{n} {k}" for k, n in noise["sigma_source"].items())
        s, q, slow = noise["sigma_m"], noise["q"], noise.get("sigma_slow_m") or {}
        if summary["tracks"] == 1:
            lines.append(f"noise: fixes {s['median']:.3g} m" + (f" white and {slow['median']:.3g} m slow" if slow
                                                                else "")
                         + f" (1-sigma per axis, {src}), process noise q = {q['median']:.3g} "
                         f"({', '.join(noise['q_source'])})")
        else:
            lines.append(f"noise over {summary['tracks']} tracks ({src}): fixes {s['median']:.3g} m median "
                         f"(5-95 %: {s['p5']:.3g}-{s['p95']:.3g})"
                         + (f", slow error {slow['median']:.3g} m median" if slow else "")
                         + f", q {q['median']:.3g} median ({q['p5']:.3g}-{q['p95']:.3g})"
                         + ("" if track_summary else "; --track-summary FILE writes every track's estimate"))
    return lines


def _advise(summary: dict) -> None:
    """What a run's numbers suggest, on stderr: fixes without independent noise, NIS far from its band."""
    floor = (summary.get("noise") or {}).get("sigma_at_floor")
    if floor:
        note(f"{floor} track(s) show no independent fix noise (sigma at its 1 mm floor): the receiver already "
             "smooths its fixes and the estimate follows them; their error against the truth, which the fixes "
             "cannot show, is in the covariance as a slow error of the fixes' stated accuracy (5 m per axis "
             "where they state none)")
    for advice in (summary.get("nis") or {}).get("advice", []):
        note(advice, "advice")


def simulate(
    ctx: typer.Context,
    scenario: str = typer.Option("gps", "--scenario", help="gps or urban-3bts."),
    tracks: Optional[int] = typer.Option(None, "--tracks", help="Number of simulated tracks (default 10; not with "
                                                                "--along)."),
    out: Path = typer.Option(..., "--out", "-o", help="Log with truth columns: .parquet or .csv."),
    cells_out: Optional[Path] = typer.Option(None, "--cells-out", help="Cell table (cellular scenarios); "
                                                                       "default OUT with suffix .cells.csv."),
    along: Optional[Path] = typer.Option(None, "--along", help="Use the real tracks of this position-fix file "
                                                               "as truth."),
    duration: float = typer.Option(300.0, help="Seconds per simulated track."),
    interval: Optional[str] = typer.Option(None, help="Time between fixes (s): exp:MEAN[:MIN] (gps default "
                                                      "exp:2:0.2), uniform:MIN:MAX or MIN:MAX, or DT (a regular "
                                                      "grid; urban-3bts default 1)."),
    q: float = typer.Option(0.5, "--q", help="Process-noise density of the truth (m^2/s^3)."),
    speed: float = typer.Option(10.0, help="Start speed of the truth (m/s)."),
    sigma: Optional[float] = typer.Option(None, help="gps: fix noise, 1-sigma per axis (m; default 5)."),
    outliers: Optional[float] = typer.Option(None, help="gps: fraction of outliers (default 0.02)."),
    accuracy: Optional[bool] = typer.Option(None, "--accuracy/--no-accuracy",
                                            help="gps: write the accuracy_m column (default: yes)."),
    seed: int = typer.Option(0, help="Seed of the random generator."),
    columns: Optional[str] = _ALONG_READING.columns,
    time_unit: str = _ALONG_READING.time_unit,
    time_format: Optional[str] = _ALONG_READING.time_format,
    coord_unit: str = _ALONG_READING.coord_unit,
    timezone: Optional[str] = _ALONG_READING.timezone,
    quiet: bool = QUIET,
    verbose: bool = VERBOSE,
    json_out: bool = JSON,
) -> None:
    """Simulate measurement logs with truth (GPS fixes or cellular RSS scans)."""
    if along is not None:
        reject_given(ctx, ["tracks", "duration_s", "interval", "q", "speed_mps"],
                     "does not apply with --along (the tracks of that file are the truth: one simulated track "
                     "per track of the file, at its times)")
    if scenario != "gps":
        reject_given(ctx, ["sigma_m", "outlier_rate", "accuracy_column"], f"applies to --scenario gps, not {scenario}")
    else:
        reject_given(ctx, ["cells_out"], "applies to cellular scenarios (--scenario urban-3bts)")
    import numpy as np
    import pandas as pd

    from ..io import ReadReport, write_table
    from ..runs import output_lock
    from ..tracking import simulate_chunks

    n_tracks = 10 if tracks is None else tracks
    written = {"scenario": scenario, "log": str(out), "rows": 0, "tracks": 0, "seed": seed}
    cell_tables, done = [], []

    def logs(chunks, advance):
        for log, cells in chunks:
            written["rows"] += len(log)
            n = log["track_id"].nunique()  # a chunk holds whole tracks
            written["tracks"] += n
            advance(n)
            if cells is not None:
                cell_tables.append(cells)
            yield log

    cpath = cells_out or out.with_suffix(".cells.csv")
    cells_to = cpath if cells_out or scenario != "gps" else None
    read_report = ReadReport()
    try:
        check_outputs(along, out=out, cells_out=cells_to)
        with flags_named(ctx):
            read = _read_options(ctx, columns, time_unit, time_format, coord_unit, timezone, file=along,
                                 option="--along")
            chunks = simulate_chunks(scenario, n_tracks, np.random.default_rng(seed), duration_s=duration,
                                     along=along, interval=interval, q=q, speed_mps=speed, sigma_m=sigma,
                                     outlier_rate=outliers, accuracy_column=accuracy, read=read,
                                     report=read_report)
        with output_lock(out, cells_to, note=command_line()), \
                progress(quiet or json_out) as bar, \
                bar.task("simulating tracks", total=None if along is not None else n_tracks) as advance:
            write_table(logs(chunks, advance), out)
            done.append(out)
            if cell_tables:
                write_table(pd.concat(cell_tables, ignore_index=True), cpath)
                written["cells"] = str(cpath)
    except KeyboardInterrupt:
        interrupted(f"only {done[0]} was written" if done else "nothing was written")
    except (MptrackError, OSError) as exc:
        fail(exc)
    if along is not None:
        written["read"] = read_report.to_dict()
    if json_out:
        print_json(written)
    elif not quiet:
        if along is not None:
            _skipped(written["read"], verbose)
        echo(f"{written['tracks']} tracks, {written['rows']} rows → {out}"
             + (f"; cells → {written['cells']}" if "cells" in written else ""))


def evaluate(
    ctx: typer.Context,
    tracks: Path = typer.Argument(..., help="Output of mptrack track in any of its formats: .parquet (.pq), "
                                            ".csv, .geojson (.json), .gpx or .geoparquet."),
    truth: Optional[Path] = typer.Option(None, "--truth", help="Truth in any input format: CSV (any delimiter), "
                                                                "Parquet (a file or a directory), GPX, TCX, FIT, "
                                                                "NMEA 0183 or GeoJSON (a GPS trace, a simulated log: "
                                                                "true_lat/true_lon or lat/lon; true_x/true_y or x/y "
                                                                "in metres); track_id may be left out for one "
                                                                "track."),
    report: Optional[Path] = typer.Option(None, "--report", help="Write a self-contained HTML report."),
    tolerance: Optional[float] = typer.Option(None, help="With --truth: max time difference (s) to match an "
                                                         "estimate with truth (default 0.5)."),
    columns: Optional[str] = _TRUTH_READING.columns,
    time_unit: str = _TRUTH_READING.time_unit,
    time_format: Optional[str] = _TRUTH_READING.time_format,
    coord_unit: str = _TRUTH_READING.coord_unit,
    timezone: Optional[str] = _TRUTH_READING.timezone,
    quiet: bool = QUIET,
    verbose: bool = VERBOSE,
    json_out: bool = JSON,
) -> None:
    """RMSE, NEES/NIS consistency and the error CDF of a track table against truth."""
    if truth is None:
        reject_given(ctx, ["tolerance_s"], "applies with --truth")
    from ..errors import DataError
    from ..io import ReadReport, read_output
    from ..runs import output_lock
    from ..tracking import evaluate_tracks

    held = contextlib.ExitStack()  # the report's lock, from the start to the end of the command
    truth_report = ReadReport()
    try:
        check_outputs(tracks, truth, report=report)
        read = _read_options(ctx, columns, time_unit, time_format, coord_unit, timezone, file=truth,
                             option="--truth")
        held.enter_context(output_lock(report, note=command_line()))
        if not tracks.exists():
            raise DataError("file not found", file=tracks)
        with progress(quiet or json_out) as bar:
            with bar.task("evaluating"):
                est = read_output(tracks)
                est.attrs["file"] = tracks
                with flags_named(ctx):
                    summary, table = evaluate_tracks(est, truth, tolerance_s=0.5 if tolerance is None else tolerance,
                                                     truth_file=truth, read=read, report=truth_report)
            if report is not None:
                with bar.task("report"):
                    from ..report import write_report

                    write_report(table, report, summary=summary, run={"nis": {"advice": summary["nis"]["advice"]}},
                                 title=f"mptrack evaluate {tracks.name}")
    except KeyboardInterrupt:
        interrupted("nothing was written")
    except (MptrackError, OSError) as exc:
        fail(exc)
    finally:
        held.close()
    if truth is not None:
        summary["truth_read"] = truth_report.to_dict()
    if json_out:
        print_json(summary)
        return
    if quiet:
        return
    if truth is not None:
        _skipped(summary["truth_read"], verbose)
    o = summary["overall"]
    out_print(_summary_table(summary, f"Evaluation of {tracks.name}", None if verbose else 30))
    line = f"{len(summary['tracks'])} tracks, {o['points']} points"
    if "rmse_m" in o:
        line += f", RMSE {o['rmse_m']:.2f} m, 95 % error {o['cdf95_m']:.2f} m, mean NEES {o['mean_nees']:.3g}"
    echo(line)
    _nis_line(summary["nis"])
    _advise({"nis": summary["nis"]})
