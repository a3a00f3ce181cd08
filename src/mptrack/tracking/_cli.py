"""``mptrack track``, ``mptrack simulate`` and ``mptrack evaluate``.

The three commands are plain functions, mounted on the main app with
``app.command()(track)`` etc.; :data:`app` here mounts them alone (tests, and
``python -m mptrack.tracking._cli``).  Errors in the input exit with status 2
and a message naming file, row and column; nothing is written then.  An output
that cannot be written (another run holds its lock, a directory, a read-only
directory, a full disk, a file that vanished) exits with status 2 and one line
naming the path and the cause; Ctrl-C exits with status 130 and one line.  When
``track`` stops that way after finishing some chunks, the line says where they
were kept and gives the command that resumes the run.
"""

from __future__ import annotations

import contextlib
import json
import shlex
import shutil
import sys
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table as RichTable

from ..errors import MptrackError

__all__ = ["track", "simulate", "evaluate", "app"]

_out = Console()
_err = Console(stderr=True)


def _fail(exc: BaseException, kept: str = "") -> None:
    """One line on stderr and exit status 2: an MptrackError's message, or an OSError's path and cause."""
    _err.print(f"[red]error:[/red] {escape(_reason(exc) + kept)}", highlight=False, soft_wrap=True)
    raise typer.Exit(2)


def _reason(exc: BaseException) -> str:
    if isinstance(exc, MptrackError) or not isinstance(exc, OSError):
        return str(exc)
    if exc.filename is not None and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return (str(exc).splitlines() or [type(exc).__name__])[0]


def _interrupted(what: str) -> None:
    """Ctrl-C: one line saying what was kept, exit status 130."""
    _err.print(escape(f"interrupted; {what}"), highlight=False, soft_wrap=True)
    raise typer.Exit(130)


def _shortest(path: str) -> str:
    """A program's path as typed: its bare name when the shell finds this very file by that name."""
    name = Path(path).name
    found = shutil.which(name)
    return name if found and Path(found).absolute() == Path(path).absolute() else path


def _command(resume: bool = False) -> str:
    """This run's command line as the user can type it again (in the same directory), with ``--resume``
    added when asked."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is not None and spec.name.startswith("mptrack"):  # python -m mptrack.cli ...
        head = [_shortest(sys.executable), "-m", spec.name.removesuffix(".__main__")]
    else:
        head = [_shortest(sys.argv[0])]
    args = sys.argv[1:]
    return shlex.join(head + args + (["--resume"] if resume and "--resume" not in args else []))


def _kept(out: Path) -> str:
    """What a stopped ``track`` run kept for ``--resume`` ("" when nothing)."""
    from ..io import PartStore

    try:
        store = PartStore(out)
    except MptrackError:
        return ""
    n = len(store.parts("tracks"))
    if not n:
        return ""
    return (f"; {n} finished chunk{'s' if n != 1 else ''} kept in {store.dir}; "
            f"resume with: {_command(resume=True)}")


def _json(data) -> None:
    sys.stdout.write(json.dumps(data, indent=2, default=str, allow_nan=True) + "\n")


def _options(cls, **values):
    """``cls(**values)``, its errors naming the command-line option (--time-unit) instead of the argument."""
    from ..errors import ParameterError

    try:
        return cls(**values)
    except ParameterError as exc:
        name, _, rest = str(exc).partition(":")
        raise ParameterError(f"--{name.replace('_', '-')}:{rest}") from None


def _skipped(read: dict) -> None:
    for note in read.get("notes", ()):
        _err.print(f"[yellow]note:[/yellow] {note}", highlight=False, soft_wrap=True)
    if read.get("rows_skipped"):
        _err.print(f"[yellow]skipped {read['rows_skipped']} of {read['rows_read']} rows of {read['file']}:[/yellow]",
                   highlight=False)
        for reason, count in read["skipped_by_reason"].items():
            _err.print(f"  {count} × {reason}", highlight=False)


_TERMINAL_COLUMNS = ("points", "outliers", "rmse_m", "cdf95_m", "mean_nees", "nees_in_95", "mean_nis", "nis_in_95")


def _summary_table(summary: dict, title: str) -> RichTable:
    rows = {"all": summary["overall"], **dict(list(summary["tracks"].items())[:30])}
    cols = [c for c in _TERMINAL_COLUMNS if any(c in r for r in rows.values())]
    rt = RichTable(title=title, title_justify="left")
    rt.add_column("track")
    for c in cols:
        rt.add_column(c, justify="right")
    for k, r in rows.items():
        rt.add_row(k, *[f"{r[c]:.4g}" if isinstance(r.get(c), float) else str(r.get(c, "")) for c in cols])
    return rt


def track(
    input: Path = typer.Argument(..., help="Position fixes: CSV (any delimiter), Parquet (a file or a directory), "
                                           "GPX, TCX, FIT, NMEA 0183 or GeoJSON; or, with --cells, a cellular "
                                           "measurement log (CSV/Parquet)."),
    out: Path = typer.Option(..., "--out", "-o", help="Result: .parquet, .csv, .geojson, .gpx or .geoparquet "
                                                      "(written atomically; the input's other columns pass "
                                                      "through)."),
    cells: Optional[Path] = typer.Option(None, "--cells", help="Cell table (OpenCelliD layout): track cellular "
                                                               "measurements with --method."),
    method: str = typer.Option("ekf", help="Cellular filter: ekf, fekf or fcs."),
    motion: str = typer.Option("random-walk", help="Cellular motion model: random-walk or cv."),
    model: str = typer.Option("cv", help="Motion model for position fixes: cv or ca."),
    filter: str = typer.Option("kf", "--filter", help="Position-fix filter: kf (gated, irregular times) or a "
                                                      "linear filter name (lf, sskf, ...) on a regular grid."),
    smooth: bool = typer.Option(False, "--smooth", help="Add an RTS smoothing pass."),
    q: Optional[float] = typer.Option(None, help="Process-noise density (m^2/s^3 for cv). Default: estimated "
                                                 "from each track."),
    sigma: Optional[float] = typer.Option(None, help="Fix noise (1-sigma per axis, m) where the input has no "
                                                     "accuracy_m. Default: estimated from each track (with "
                                                     "accuracy_m: a scale factor on it)."),
    noise: str = typer.Option("track", help="track: estimate the noise per track (short tracks share one "
                                            "estimate); file: one estimate for the whole input."),
    gate: float = typer.Option(0.999, help="NIS gate probability (chi-square); 1 disables gating."),
    report: Optional[Path] = typer.Option(None, "--report", help="Also write a self-contained HTML report."),
    track_summary: Optional[Path] = typer.Option(None, "--track-summary", help="Also write the per-track table "
                                                 "(noise estimates with standard errors, counts, NIS): "
                                                 ".parquet or .csv."),
    on_error: str = typer.Option("raise", "--on-error", help="raise: stop at the first bad row; skip: drop bad "
                                                             "rows, count and report them."),
    max_skip: str = typer.Option("1%", "--max-skip", help="With --on-error skip: fail (nothing written) when more "
                                                          "rows than this are dropped: a percentage of the rows "
                                                          "read or a count."),
    columns: Optional[str] = typer.Option(None, "--columns", help="Which column is which where the names are not "
                                                                  "recognised: time=ts,lat=Latitude,lon=Lng,"
                                                                  "track_id=device,accuracy_m=acc."),
    time_unit: str = typer.Option("auto", "--time-unit", help="Unit of numeric time stamps: auto (by magnitude), "
                                                              "s, ms, us or ns."),
    time_format: Optional[str] = typer.Option(None, "--time-format", help="Layout of text time stamps that are "
                                                                          "not ISO 8601, e.g. '%d/%m/%Y %H:%M:%S'."),
    coord_unit: str = typer.Option("auto", "--coord-unit", help="Unit of lat/lon: auto, deg, deg-e7 or deg-e6 "
                                                                "(integer degrees x 10^7 / 10^6) or rad."),
    resume: bool = typer.Option(False, "--resume", help="Keep the work of an interrupted run of the same input "
                                                        "and options."),
    executor: str = typer.Option("serial", help="serial, processes or dask: who runs the chunks (the output "
                                                "is the same)."),
    workers: Optional[int] = typer.Option(None, "--workers", help="Processes / Dask workers (default: cores)."),
    chunk_rows: int = typer.Option(200_000, "--chunk-rows", help="Rows of whole tracks per chunk (memory)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar; only the summary lines."),
    json_out: bool = typer.Option(False, "--json", help="Print the run summary as JSON on stdout."),
) -> None:
    """Track position fixes or cellular measurements; write estimates, covariances, NIS and flags.

    With no --sigma/--q the fix noise and the process noise are estimated from each track."""
    from .._progress import RichProgress
    from ..io import ReadOptions
    from ._fixes import TrackOptions
    from .._validation import check_outputs
    from ._pipeline import read_output, track_file

    from .._io import output_lock

    kept, summary = "", None
    try:
        check_outputs(input, cells, report=report)
        options = TrackOptions(model=model, filter=filter, q=q, sigma_m=sigma, noise=noise, smooth=smooth,
                               gate_probability=None if gate >= 1 else gate, method=method, motion=motion)
        read = _options(ReadOptions, columns=columns or (), time_unit=time_unit, time_format=time_format,
                        coord_unit=coord_unit, max_skip=max_skip)
        with output_lock(out, track_summary, report, note=_command()):
            try:
                with RichProgress(console=_err, disable=quiet or json_out) as progress:
                    summary = track_file(input, out, cells=cells, options=options, on_error=on_error,
                                         read=read, resume=resume, executor=executor, max_workers=workers,
                                         chunk_rows=chunk_rows, track_summary=track_summary, progress=progress)
                if report is not None:
                    from ..report import write_report

                    write_report(read_output(out), report, title=f"mptrack track {input.name}")
                    summary["report"] = str(report)
            except (OSError, KeyboardInterrupt):
                kept = _kept(out)  # under the lock: the parts are this run's
                raise
    except KeyboardInterrupt:
        _interrupted(f"{out} is complete, the report was not written" if summary is not None
                     else kept.removeprefix("; ") or "nothing was kept")
    except (MptrackError, OSError) as exc:
        _fail(exc, kept)
    if json_out:
        _json(summary)
        return
    _skipped(summary["read"])
    _out.print(f"{summary['tracks']} tracks ({summary['tracks_resumed']} resumed), {summary['points_written']} "
               f"points, {summary['outliers_rejected']} outliers rejected → {out}"
               + (f"; report {report}" if report else "") + (f"; tracks {track_summary}" if track_summary else ""),
               highlight=False, soft_wrap=True)
    if 1 < len(summary.get("track_noise", ())) <= 10:
        _out.print(_noise_table(summary["track_noise"]))
    for line in _noise_lines(summary, track_summary):
        _out.print(line, highlight=False, soft_wrap=True)


def _noise_table(rows: list[dict]) -> RichTable:
    """The noise of each track (a few tracks): estimate ± standard error and where it came from."""
    rt = RichTable(title="noise per track", title_justify="left")
    for col in ("track", "fixes", "sigma (m)", "q", "from", "mean NIS"):
        rt.add_column(col, justify="left" if col in ("track", "from") else "right")

    def pm(v, se):
        return f"{v:.3g}" + (f" ± {se:.2g}" if se is not None else "")

    for r in rows:
        src = r["sigma_source"] if r["sigma_source"] == r["q_source"] else f"{r['sigma_source']}/{r['q_source']}"
        nis = "" if r["mean_nis"] is None else f"{r['mean_nis']:.2f}"
        rt.add_row(str(r["track_id"]), str(r["fixes"]), pm(r["sigma_m"], r["sigma_se_m"]), pm(r["q"], r["q_se"]),
                   src, nis)
    return rt


def _noise_lines(summary: dict, track_summary) -> list[str]:
    """The noise the run used, in a sentence (one track) or as medians and ranges (many), and the NIS advice."""
    noise = summary.get("noise")
    lines = []
    if noise:
        src = ", ".join(f"{n} {k}" for k, n in noise["sigma_source"].items())
        s, q = noise["sigma_m"], noise["q"]
        if summary["tracks"] == 1:
            lines.append(f"noise: fixes {s['median']:.3g} m (1-sigma per axis, {src}), process noise "
                         f"q = {q['median']:.3g} ({', '.join(noise['q_source'])})")
        else:
            lines.append(f"noise over {summary['tracks']} tracks ({src}): fixes {s['median']:.3g} m median "
                         f"(5-95 %: {s['p5']:.3g}-{s['p95']:.3g}), q {q['median']:.3g} median "
                         f"({q['p5']:.3g}-{q['p95']:.3g})"
                         + ("" if track_summary else "; --track-summary FILE writes every track's estimate"))
        if noise.get("sigma_at_floor"):
            lines.append(f"{noise['sigma_at_floor']} track(s) show no independent fix noise (sigma at its 1 mm "
                         "floor): the receiver already smooths its fixes, the estimate follows them, and its "
                         "covariance covers the noise between fixes, not the receiver's own error (metres)")
    lines += summary.get("nis", {}).get("advice", [])
    return lines


_SIMULATE_OPTIONS = {"tracks": "--tracks", "duration_s": "--duration", "interval": "--interval", "q": "--q",
                     "speed_mps": "--speed", "sigma_m": "--sigma", "outlier_rate": "--outliers",
                     "accuracy_column": "--no-accuracy"}


def simulate(
    scenario: str = typer.Option("gps", "--scenario", help="gps or urban-3bts."),
    tracks: int = typer.Option(10, "--tracks", help="Number of simulated tracks (ignored with --along)."),
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
    quiet: bool = typer.Option(False, "--quiet", "-q"),
    json_out: bool = typer.Option(False, "--json", help="Print what was written as JSON."),
) -> None:
    """Simulate measurement logs with truth (GPS fixes or cellular RSS scans)."""
    import numpy as np
    import pandas as pd

    from .._io import output_lock
    from .._validation import check_outputs
    from ..errors import ParameterError
    from ..io import write_table
    from ._simulate import simulate_chunks

    written = {"scenario": scenario, "log": str(out), "rows": 0, "tracks": 0, "seed": seed}
    cell_tables, done = [], []

    def logs(chunks):
        for log, cells in chunks:
            written["rows"] += len(log)
            written["tracks"] += log["track_id"].nunique()  # a chunk holds whole tracks
            if cells is not None:
                cell_tables.append(cells)
            yield log

    try:
        check_outputs(along, out=out, cells_out=cells_out)
        try:
            chunks = simulate_chunks(scenario, tracks, np.random.default_rng(seed), duration_s=duration,
                                     along=along, interval=interval, q=q, speed_mps=speed, sigma_m=sigma,
                                     outlier_rate=outliers, accuracy_column=accuracy)
        except ParameterError as exc:  # name the option, not the library's argument
            name, _, rest = str(exc).partition(":")
            raise ParameterError(f"{_SIMULATE_OPTIONS.get(name, name)}:{rest}") from None
        cpath = cells_out or out.with_suffix(".cells.csv")
        with output_lock(out, cpath if cells_out or scenario != "gps" else None, note=_command()), \
                _err.status("simulating…", spinner="dots") if not (quiet or json_out) else _nullctx():
            write_table(logs(chunks), out)
            done.append(out)
            if cell_tables:
                write_table(pd.concat(cell_tables, ignore_index=True), cpath)
                written["cells"] = str(cpath)
    except KeyboardInterrupt:
        _interrupted(f"only {done[0]} was written" if done else "nothing was written")
    except (MptrackError, OSError) as exc:
        _fail(exc)
    if json_out:
        _json(written)
    else:
        _out.print(f"{written['tracks']} tracks, {written['rows']} rows → {out}"
                   + (f"; cells → {written['cells']}" if "cells" in written else ""), highlight=False)


def _nullctx():
    return contextlib.nullcontext()


def evaluate(
    tracks: Path = typer.Argument(..., help="Output of mptrack track (.parquet/.csv/.geojson)."),
    truth: Optional[Path] = typer.Option(None, "--truth", help="Truth in any input format (a GPX trace, a simulated "
                                                                "log: true_lat/true_lon or lat/lon; true_x/true_y or "
                                                                "x/y in metres); track_id may be left out for one "
                                                                "track."),
    report: Optional[Path] = typer.Option(None, "--report", help="Write a self-contained HTML report."),
    tolerance: float = typer.Option(0.5, help="Max time difference (s) to match an estimate with truth."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Only the overall line."),
    json_out: bool = typer.Option(False, "--json", help="Print the metrics as JSON on stdout."),
) -> None:
    """RMSE, NEES/NIS consistency and the error CDF of a track table against truth."""
    from .._io import output_lock
    from .._validation import check_outputs
    from ..errors import DataError
    from ._evaluate import evaluate_tracks
    from ._pipeline import read_output

    held = contextlib.ExitStack()  # the report's lock, from the start to the end of the command
    try:
        check_outputs(tracks, truth, report=report)
        held.enter_context(output_lock(report, note=_command()))
        if not tracks.exists():
            raise DataError("file not found", file=tracks)
        est = read_output(tracks)
        est.attrs["file"] = tracks
        summary, table = evaluate_tracks(est, truth, tolerance_s=tolerance, truth_file=truth)
        if report is not None:
            from ..report import write_report

            write_report(table, report, summary=summary, title=f"mptrack evaluate {tracks.name}")
    except KeyboardInterrupt:
        _interrupted("nothing was written")
    except (MptrackError, OSError) as exc:
        _fail(exc)
    finally:
        held.close()
    if json_out:
        _json(summary)
        return
    o = summary["overall"]
    if not quiet:
        _out.print(_summary_table(summary, f"Evaluation of {tracks.name}"))
    line = f"{len(summary['tracks'])} tracks, {o['points']} points"
    if "rmse_m" in o:
        line += f", RMSE {o['rmse_m']:.2f} m, 95 % error {o['cdf95_m']:.2f} m, mean NEES {o['mean_nees']:.2f}"
    line += f", mean NIS {o['mean_nis']:.2f} (dof {o['mean_nis_dof']:.2f})"
    _out.print(line, highlight=False)


app = typer.Typer(add_completion=False, no_args_is_help=True, help="mptrack tracking commands.")
app.command()(track)
app.command()(simulate)
app.command()(evaluate)

if __name__ == "__main__":  # pragma: no cover
    app()
