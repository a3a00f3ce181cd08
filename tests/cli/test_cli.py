"""The command line's conventions: --version/-V, -h everywhere, -q/-v/--json on every command, exit
codes 0/1/2/130, options that do not apply rejected, progress on stderr, whole lines in a pipe, a
fast `mptrack --help` that loads no numerical library, and the reproduction summary counts."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from mptrack import __version__
from mptrack.cli import app
from mptrack.cli._common import PAPERS, paper_names, short_paper
from mptrack.cli.reproduce import cell_counts, summary_line

from _data import REAL_TRACES

runner = CliRunner()
COMMANDS = ("track", "simulate", "evaluate", "reproduce", "bench", "filters")
SRC = str(Path(__file__).resolve().parents[2] / "src")
ENV = dict(os.environ, PYTHONPATH=SRC, MPLBACKEND="Agg", COLUMNS="80")


def cli(*args, **kw) -> subprocess.CompletedProcess:
    """``mptrack ARGS`` in a subprocess, its stdout and stderr pipes (not a terminal)."""
    return subprocess.run([sys.executable, "-m", "mptrack.cli", *map(str, args)], capture_output=True, text=True,
                          env=ENV, timeout=600, **kw)


@pytest.fixture(scope="module")
def tracks(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    gpx = d / "car.gpx"
    shutil.copy(REAL_TRACES["car"], gpx)
    res = runner.invoke(app, ["track", str(gpx), "--out", str(d / "t.parquet"), "-q"])
    assert res.exit_code == 0, res.output
    return d / "t.parquet"


# ---------------------------------------------------------------- version, help, options

@pytest.mark.parametrize("flag", ["--version", "-V"])
def test_version(flag):
    res = runner.invoke(app, [flag])
    assert res.exit_code == 0 and res.stdout == f"mptrack {__version__}\n"


@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_dash_h_everywhere_lists_quiet_verbose_and_json(command):
    res = runner.invoke(app, ([command] if command else []) + ["-h"])
    assert res.exit_code == 0 and "Usage:" in res.stdout
    assert "Exit status: 0 success, 1 internal error, 2 usage or data error, 130" in " ".join(res.stdout.split())
    if command:
        for flag in ("--quiet", "-q", "--verbose", "-v", "--json"):
            assert re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", res.stdout), (command, flag)


def test_quiet_and_verbose_run_on_every_command(tmp_path, tracks):
    runs = {"track": ["track", REAL_TRACES["car"], "--out", tmp_path / "a.parquet"],
            "simulate": ["simulate", "--tracks", "2", "--duration", "30", "--out", tmp_path / "s.csv"],
            "evaluate": ["evaluate", tracks],
            "reproduce": ["reproduce", "--list"],
            "bench": ["bench", "--list"],
            "filters": ["filters"]}
    assert set(runs) == set(COMMANDS)
    for name, args in runs.items():
        for flag in ("-q", "-v"):
            for p in tmp_path.iterdir():
                p.unlink()
            res = runner.invoke(app, [str(a) for a in args] + [flag])
            assert res.exit_code == 0, (name, flag, res.output)
    quiet = runner.invoke(app, ["filters", "-q"]).stdout
    assert quiet.strip().splitlines() == [quiet.strip()] and "KF" in quiet  # one line


def test_json_is_the_only_stdout(tmp_path, tracks):
    for args in (["evaluate", tracks], ["filters"], ["reproduce", "--list"],
                 ["track", REAL_TRACES["car"], "--out", tmp_path / "j.parquet"]):
        res = runner.invoke(app, [str(a) for a in args] + ["--json"])
        assert res.exit_code == 0, res.output
        json.loads(res.stdout)


# ---------------------------------------------------------------- exit codes

def test_exit_codes(tmp_path, monkeypatch):
    assert runner.invoke(app, ["track", str(REAL_TRACES["car"]), "--no-such-option"]).exit_code == 2
    res = runner.invoke(app, ["track", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "o.parquet"), "-q"])
    assert res.exit_code == 2 and res.stderr.startswith("error:") and len(res.stderr.splitlines()) == 1
    import mptrack.tracking as tracking

    def boom(*a, **k):
        raise RuntimeError("a bug")

    monkeypatch.setattr(tracking, "track_file", boom)
    res = runner.invoke(app, ["track", str(REAL_TRACES["car"]), "--out", str(tmp_path / "o.parquet")])
    assert res.exit_code == 1 and isinstance(res.exception, RuntimeError)  # a bug: exit 1, with its traceback

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(tracking, "track_file", interrupt)
    res = runner.invoke(app, ["track", str(REAL_TRACES["car"]), "--out", str(tmp_path / "o.parquet")])
    assert res.exit_code == 130 and res.stderr.startswith("interrupted; ")
    assert not (tmp_path / "o.parquet").exists()


# ---------------------------------------------------------------- options that do not apply

@pytest.mark.parametrize("args, message", [
    (["track", "IN", "--method", "fekf"], "--method applies to cellular measurements only"),
    (["track", "IN", "--motion", "cv"], "--motion applies to cellular measurements only"),
    (["track", "IN", "--cells", "CELLS", "--sigma", "5"], "--sigma applies to position fixes"),
    (["track", "IN", "--cells", "CELLS", "--smooth"], "--smooth applies to position fixes"),
    (["track", "IN", "--workers", "2"], "--workers applies to --executor processes or dask"),
    (["track", "IN", "--max-skip", "5"], "--max-skip applies to --on-error skip"),
    (["simulate", "--along", "IN", "--tracks", "3", "--out", "OUT"], "--tracks does not apply with --along"),
    (["simulate", "--scenario", "urban-3bts", "--sigma", "3", "--out", "OUT"], "--sigma applies to --scenario gps"),
    (["simulate", "--cells-out", "C.csv", "--out", "OUT"], "--cells-out applies to cellular scenarios"),
    (["evaluate", "IN", "--tolerance", "1"], "--tolerance applies with --truth"),
    (["simulate", "--along", "IN", "--duration", "100", "--out", "OUT"], "--duration does not apply with --along"),
    (["simulate", "--along", "IN", "--speed", "5", "--out", "OUT"], "--speed does not apply with --along"),
    (["simulate", "--along", "IN", "--interval", "2", "--out", "OUT"], "--interval does not apply with --along"),
    (["simulate", "--along", "IN", "--q", "3", "--out", "OUT"], "--q does not apply with --along"),
    (["simulate", "--out", "OUT", "--scenario", "urban-3bts", "--accuracy"], "--accuracy applies to"),
    (["simulate", "--out", "OUT", "--scenario", "urban-3bts", "--no-accuracy"], "--no-accuracy applies to"),
    (["reproduce", "--list", "--no-resume"], "--no-resume applies to a reproduction run"),
    (["bench", "--list", "--save", "OUT"], "--save does not apply with --list"),
    (["bench", "--list", "--quick"], "--quick does not apply with --list"),
    (["bench", "--list", "--suite", "linear"], "--suite does not apply with --list"),
    (["reproduce", "--list", "--report"], "--report applies to a reproduction run, not to the list"),
    (["reproduce", "--list", "--quick"], "--quick applies to a reproduction run, not to the list"),
    (["reproduce", "--list", "--seed", "3"], "--seed applies to a reproduction run, not to the list"),
    (["reproduce", "--list", "--out", "OUT"], "--out applies to a reproduction run, not to the list"),
    (["reproduce", "--seed", "3"], "--seed applies to a reproduction run, not to the list"),
    (["reproduce", "--list", "zhao2013"], "--list lists the reproductions and runs none"),
    (["track", "IN", "--max-skip", "1%"], "--max-skip applies to --on-error skip"),  # given, even at its default
    (["track", "IN", "--cells", "CELLS", "--gate", "0.99"], "--gate applies to position fixes"),
])
def test_options_that_do_not_apply_are_rejected(tmp_path, args, message):
    subst = {"IN": str(REAL_TRACES["car"]), "CELLS": str(tmp_path / "cells.csv"), "OUT": str(tmp_path / "o.csv")}
    out = ["--out", str(tmp_path / "t.parquet")] if args[0] == "track" else []  # not beside the input
    res = runner.invoke(app, [subst.get(a, a) for a in args] + out)
    assert res.exit_code == 2 and message in res.stderr, res.output
    assert len(res.stderr.splitlines()) == 1 and res.stdout == ""
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["track", "IN", "--sigma", "-1"], "--sigma: expected a finite number > 0, got -1.0"),
    (["track", "IN", "--gate", "-0.5"], "--gate:"),
    (["track", "IN", "--chunk-rows", "0"], "--chunk-rows: expected an integer >= 1, got 0"),
    (["track", "IN", "--model", "xx"], "--model: unknown motion model 'xx'; known: cv, ca"),
    (["track", "IN", "--time-unit", "zz"], "--time-unit: expected one of"),
    (["track", "IN", "--cells", "CELLS", "--range-sigma", "-5"], "--range-sigma: expected a finite number > 0"),
    (["simulate", "--duration", "-5", "--out", "OUT"], "--duration: expected a finite number > 0"),
    (["simulate", "--interval", "zz", "--out", "OUT"], "--interval: expected"),
    (["simulate", "--sigma", "-2", "--out", "OUT"], "--sigma:"),
    (["evaluate", "TRACKS", "--truth", "IN", "--tolerance", "-1"], "--tolerance: expected a finite number >= 0"),
])
def test_errors_name_the_option_the_user_typed(tmp_path, tracks, args, message):
    """A bad value is one line naming the option as typed (--sigma), never the library's argument (sigma_m)."""
    subst = {"IN": str(REAL_TRACES["car"]), "CELLS": str(tmp_path / "cells.csv"), "OUT": str(tmp_path / "o.csv"),
             "TRACKS": str(tracks)}
    (tmp_path / "cells.csv").write_text("radio,mcc,net,area,cell,lon,lat\n")
    res = runner.invoke(app, [subst.get(a, a) for a in args] + ["--out" if args[0] == "track" else "-q",
                                                               *([str(tmp_path / "t.parquet")] if args[0] == "track"
                                                                 else [])])
    assert res.exit_code == 2, res.output
    line = res.stderr.strip().splitlines()[-1]
    assert line.startswith("error: ") and message in line, res.stderr
    assert not re.search(r"\b(sigma_m|gate_probability|chunk_rows|time_unit|r_km2|duration_s|tolerance_s)\b", line)


def test_json_of_a_gps_run_lists_only_its_options(tmp_path):
    res = runner.invoke(app, ["track", str(REAL_TRACES["car"]), "--out", str(tmp_path / "t.parquet"), "--json"])
    options = json.loads(res.stdout)["options"]
    assert "model" in options and not {"method", "motion", "q_km2", "r_km2"} & set(options)


def test_out_defaults_to_a_file_beside_the_input(tmp_path):
    gpx = tmp_path / "drive.gpx"
    shutil.copy(REAL_TRACES["car"], gpx)
    res = runner.invoke(app, ["track", str(gpx)])
    assert res.exit_code == 0 and (tmp_path / "drive.tracks.parquet").exists()
    assert f"→ {tmp_path / 'drive.tracks.parquet'}" in res.stdout


# ---------------------------------------------------------------- pipes, progress

def test_piped_output_is_whole_lines_and_progress_goes_to_stderr(tmp_path):
    deep = tmp_path / ("a-long-directory-name-" * 4) / "still-going"
    deep.mkdir(parents=True)
    res = cli("simulate", "--tracks", "3", "--duration", "60", "--out", deep / "sim.parquet", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout == f"3 tracks, {res.stdout.split()[2]} rows → {deep / 'sim.parquet'}\n"  # one line, > 80 cols
    assert len(res.stdout) > 120
    assert res.stderr.splitlines()[0] == "simulating tracks ... (3)"  # progress: lines on stderr in a pipe
    assert re.fullmatch(r"simulating tracks: 3 done in \d+\.\d s", res.stderr.splitlines()[-1])
    quiet = cli("simulate", "--tracks", "3", "--duration", "60", "--out", tmp_path / "q.parquet", "-q")
    assert quiet.returncode == 0 and quiet.stderr == ""
    res = cli("track", deep / "sim.parquet", "--out", deep / "t.parquet", "--report", deep / "r.html")
    assert res.returncode == 0 and "report ..." in res.stderr
    assert res.stdout.splitlines()[0].endswith(f"; report {deep / 'r.html'}")


def test_evaluate_tables_show_four_significant_digits_and_json_every_digit(tracks):
    """No 16-digit floats in evaluate's table (in a pipe too); --json keeps every digit."""
    res = cli("evaluate", tracks)
    assert res.returncode == 0, res.stderr
    table = res.stdout.split("\n1 tracks")[0]
    cells = re.findall(r"(?<![\w.])-?\d+\.\d+(?:e[+-]\d+)?", table)
    assert cells and all(len(re.sub(r"[^\d]|e.*", "", c).lstrip("0")) <= 4 for c in cells), table
    full = json.loads(cli("evaluate", tracks, "--json").stdout)["overall"]["mean_nis"]
    assert f"{full:.4g}" in table and len(repr(full)) > 8


def test_help_is_not_wrapped_in_a_pipe():
    """Piped (COLUMNS=80), help is plain text with one line per option and per paragraph."""
    res = cli("track", "-h")
    assert res.returncode == 0 and "Usage:" in res.stdout
    lines = res.stdout.splitlines()
    out = next(line for line in lines if "--out" in line)
    assert out.rstrip().endswith("Default: INPUT.tracks.parquet beside the input."), out
    assert max(map(len, lines)) > 120 and not re.search("[╭│╰─]", res.stdout)
    epilog = cli("-h").stdout
    assert any(line.strip().startswith("Exit status: 0 success") and line.rstrip().endswith("errors to stderr.")
               for line in epilog.splitlines()), epilog


def test_results_on_stdout_notes_and_advice_on_stderr(tmp_path, tracks, monkeypatch):
    res = runner.invoke(app, ["track", str(REAL_TRACES["car"]), "--out", str(tmp_path / "a.parquet")])
    assert res.exit_code == 0, res.output
    assert "note: 1 track(s) show no independent fix noise" in res.stderr and "independent" not in res.stdout
    assert res.stdout.startswith("1 tracks") and "noise: fixes" in res.stdout
    res = runner.invoke(app, ["track", str(REAL_TRACES["car"]), "--sigma", "50", "--out", str(tmp_path / "b.parquet")])
    assert "advice: 1 track(s) have a mean NIS far below its band" in res.stderr and "advice" not in res.stdout
    res = runner.invoke(app, ["evaluate", str(tmp_path / "b.parquet")])
    assert "advice: 1 track(s) have a mean NIS far below" in res.stderr and "advice" not in res.stdout
    import mptrack.experiments as experiments
    from mptrack.experiments._results import Reproduction, Table

    def fake(key, out, **kw):
        return Reproduction(key=key, paper="Zhao, Chen & Ma (2013), An FEM", seed=1, parameters={},
                            tables={"t": Table("t", ["a", "b"], [["r", 1.0]])}, notes=["a note (seed 004)"])

    monkeypatch.setattr(experiments, "run_experiment", fake)
    res = runner.invoke(app, ["reproduce", "zhao2013", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "note: a note (Zhao et al. 2013)" in res.stderr and "note:" not in res.stdout


def test_track_report_of_a_simulated_log_shows_its_error_against_truth(tmp_path, monkeypatch):
    """A log with truth columns (simulate): the report of `track --report` evaluates against them (error
    plot, RMSE in the table), the same numbers as `evaluate --truth LOG`; with a GeoJSON output the
    report is built from the run's points, not by reading the GeoJSON back."""
    sim = tmp_path / "s.csv"
    res = runner.invoke(app, ["simulate", "--tracks", "3", "--duration", "120", "--out", str(sim), "-q"])
    assert res.exit_code == 0, res.output
    import mptrack.io

    def read_back(*a, **k):
        raise AssertionError("the report read the output back")

    monkeypatch.setattr(mptrack.io, "read_output", read_back)
    out, page = tmp_path / "t.geojson", tmp_path / "r.html"
    res = runner.invoke(app, ["track", str(sim), "--out", str(out), "--report", str(page), "-q"])
    assert res.exit_code == 0, res.output
    monkeypatch.undo()
    parquet = tmp_path / "t.parquet"  # full precision, for the comparison with evaluate
    assert runner.invoke(app, ["track", str(sim), "--out", str(parquet), "--report", str(page), "-q"]).exit_code == 0
    text = page.read_text()
    data = json.loads(re.search(r"<script type='application/json' id='mptrack-data'>(.*?)</script>", text,
                                re.S).group(1))
    assert data["payload"]["has_error"] and all("err" in tr for tr in data["payload"]["tracks"])
    summary = dict(zip(data["summary"]["columns"], data["summary"]["overall"]))
    ev = json.loads(runner.invoke(app, ["evaluate", str(parquet), "--truth", str(sim), "--json"]).stdout)["overall"]
    assert summary["rmse_m"] == pytest.approx(ev["rmse_m"], rel=1e-9) and summary["rmse_m"] > 0
    assert summary["matched_points"] == ev["matched_points"] == ev["points"]
    assert "truth (dashed black line)" in text


def test_tracking_progress_counts_tracks_not_chunks(tmp_path):
    sim = tmp_path / "s.parquet"
    assert runner.invoke(app, ["simulate", "--tracks", "5", "--duration", "60", "--out", str(sim), "-q"]).exit_code == 0
    args = ["track", sim, "--out", tmp_path / "t.parquet", "--chunk-rows", "70"]
    chunks = json.loads(runner.invoke(app, [str(a) for a in args] + ["--json"]).stdout)["chunks"]
    assert 1 < chunks < 5  # several tracks per chunk
    res = cli(*args)
    assert res.returncode == 0, res.stderr
    assert re.search(r"^tracking the tracks of s\.parquet: 5 done in \d+\.\d s$", res.stderr, re.M), res.stderr


def test_python_dash_m_mptrack():
    res = subprocess.run([sys.executable, "-m", "mptrack", "--version"], capture_output=True, text=True, env=ENV,
                         timeout=120)
    assert res.returncode == 0 and res.stdout == f"mptrack {__version__}\n", res.stderr
    res = subprocess.run([sys.executable, "-m", "mptrack", "reproduce", "--list", "--quick"], capture_output=True,
                         text=True, env=ENV, timeout=120)
    assert res.returncode == 2 and res.stderr.startswith("error: --quick")


def test_bench_figure_keeps_three_significant_figures_with_their_trailing_zeros():
    from mptrack.cli.bench import figure

    values = (0.18, 1.2033342500217259e-05, 2.41e8, 1234.5, 1.0, 0.0989, None, 7)
    assert [figure(v) for v in values] == ["0.180", "1.20e-05", "2.41e+08", "1234", "1.00", "0.0989", "—", "7"]


def test_bench_tables_show_three_significant_figures_and_json_every_digit():
    res = cli("bench", "--quick", "--suite", "linear")
    assert res.returncode == 0, res.stderr
    assert "…" not in res.stdout
    cells = [c.strip() for line in res.stdout.splitlines() if line.startswith("│") for c in line.split("│")[2:-1]]
    assert len(cells) > 20 and "1.00" in cells, res.stdout
    three = re.compile(r"-?(\d{1,5}|\d\.\d\d|\d\d\.\d|0\.0*[1-9]\d{0,2}|\d(\.\d{1,2})?e[+-]\d\d)")
    assert all(three.fullmatch(c) for c in cells), cells     # 0.0924, 1.10, 2.02e+05; not 1.2033342500217259e-05
    res = cli("bench", "--quick", "--suite", "linear", "--json")
    values = [v for row in json.loads(res.stdout)["reports"][0]["rows"] for v in row if isinstance(v, float)]
    assert any(len(repr(v)) > 8 for v in values)           # the JSON keeps every digit


# ---------------------------------------------------------------- mptrack --help is fast

def test_help_imports_no_numerical_library():
    code = ("import sys; sys.argv = ['mptrack', '--help']\n"
            "from mptrack.cli import app\n"
            "try:\n    app()\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('numba', 'scipy', 'pandas', 'matplotlib', 'numpy', 'pyarrow') "
            "if m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV, timeout=60)
    assert res.returncode == 0 and res.stdout.strip().splitlines()[-1] == "[]", res.stdout + res.stderr


# ---------------------------------------------------------------- papers and reproductions

def test_papers_are_named_by_author_and_year():
    assert paper_names("KF (seed 000 eq. 4); seed 004 section 3") == "KF (Assimakis & Adam 2014 eq. 4); " \
                                                                    "Zhao et al. 2013 section 3"
    # one short name per paper, everywhere: the seed numbers' names are the reproductions' own
    from mptrack.experiments import experiments

    reg = experiments()
    for seed, key in {"000": "assimakis2014", "001": "assimakis2016", "002": "assimakis2015", "003": "bouzera2017",
                      "004": "zhao2013"}.items():
        assert PAPERS[seed] == short_paper(reg[key].paper), key
    assert short_paper("Assimakis, Tziallas, Adam, Polyzos & Papanastasiou (2016), Mobile") == "Assimakis et al. 2016"
    assert short_paper("Assimakis & Adam (2014), Global") == "Assimakis & Adam 2014"
    res = runner.invoke(app, ["filters"])
    assert "seed" not in res.stdout and "Assimakis & Adam 2014" in res.stdout
    res = runner.invoke(app, ["reproduce", "--list"])
    assert "seed 0" not in res.stdout


RESULTS = {"key": "x", "paper": "Zhao, Chen & Ma (2013), An FEM", "figures": {}, "elapsed_s": 1.0,
           "tables": {"Table 1": {"title": "t", "columns": ["a", "b", "c"],
                                  "rows": [["r0", 1.0, 2.0], ["r1", 3.0, "x"]],
                                  "paper": [["r0", 1.0, 2.5], ["r1", 3.5, None]],
                                  "mismatches": [[0, 2], [1, 1]]},
                      "ours": {"title": "o", "columns": ["a", "b"], "rows": [["r", 1.0]]}}}


def test_reproduce_counts_fall_back_to_matched_over_published():
    """A results.json without "comparison" (written before it existed): counted from the tables."""
    assert cell_counts(RESULTS) == {"published": 3, "matched": 1, "explained": 0, "unexplained": 2}
    line = summary_line("x", RESULTS, Path("out/x/results.json"))
    assert line.startswith("x (Zhao et al. 2013): 1/3 published numbers matched, 0 differ for a documented "
                           "reason, 2 differ unexplained (see docs/errata.md)")
    results = json.loads(json.dumps(RESULTS))
    results["tables"]["Table 1"]["explained_by"] = [[0, 2, "typo"]]
    assert cell_counts(results) == {"published": 3, "matched": 1, "explained": 1, "unexplained": 1}
    results["tables"]["Table 1"].update(uncounted=["b"], mismatches=[[0, 2]])  # column b repeats inputs
    assert cell_counts(results) == {"published": 1, "matched": 0, "explained": 1, "unexplained": 0}


def test_reproduce_counts_come_from_the_comparison():
    results = dict(RESULTS, comparison={"compared": 9, "matched": 5, "differing_explained": 4,
                                        "differing_unexplained": 0})
    assert cell_counts(results) == {"published": 9, "matched": 5, "explained": 4, "unexplained": 0}
    assert "5/9 published numbers matched, 4 differ for a documented reason, 0 differ unexplained" in \
        summary_line("x", results, Path("r.json"))


def test_reproduce_writes_results_and_its_report(tmp_path):
    result = runner.invoke(app, ["reproduce", "assimakis2015", "--out", str(tmp_path), "--quick", "--quiet",
                                 "--report"])
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "assimakis2015" / "results.json").read_text())
    assert data["tables"]["Table 3"]["mismatches"] == []
    assert result.stdout == ""  # --quiet: nothing but errors
    line = summary_line("assimakis2015", data, tmp_path / "assimakis2015" / "results.json")
    assert re.match(r"assimakis2015 \(Assimakis & Adam 2015\): 15/15 published numbers "
                    r"matched, 0 differ for a documented reason, 0 differ unexplained "
                    r"\(see docs/errata\.md\); 3 figures", line), line
    page = (tmp_path / "assimakis2015" / "report.html").read_text()
    assert "class='differs'" not in page and page.count("class='same'") == 15 and "data:image/png;base64" in page
    assert page.count("not counted: an input or label") == 42  # Table 2's formulas, Table 3's labels: plain
    assert "<title>assimakis2015: Assimakis &amp; Adam 2015</title>" in page


def test_reproduction_report_links_explained_cells(tmp_path):
    from mptrack.report import write_reproduction_report

    results = json.loads(json.dumps(RESULTS))
    results["tables"]["Table 1"]["explained_by"] = [[0, 2, "zhao2013-typo"]]
    results["errata"] = {"zhao2013-typo": "Table 1 has a typo in row 0: the paper prints 2.5"}
    errata = tmp_path / "errata.md"
    errata.write_text("# Errata\n<a id=\"zhao2013-typo\"></a>\n\n## Table 1: a typo in row 0\n")
    text = write_reproduction_report(results, tmp_path / "r.html", errata=errata).read_text()
    assert text.count("class='explained'") == 1 and text.count("class='differs'") == 1
    assert f"href='{errata.as_uri()}#zhao2013-typo'" in text and "the paper prints 2.5" in text


def test_unknown_reproduction_is_a_clear_error(tmp_path):
    result = runner.invoke(app, ["reproduce", "nosuchpaper", "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert "unknown key 'nosuchpaper'" in result.stderr


def test_bench_quick_linear_saves_json(tmp_path):
    out = tmp_path / "bench.json"
    result = runner.invoke(app, ["bench", "--quick", "--suite", "linear", "--save", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())["reports"][0]
    assert report["suite"] == "linear"
    assert any(str(r[0]).startswith("implementation 12") for r in report["rows"])
    res = runner.invoke(app, ["bench", "--quick", "--suite", "linear", "--json"])
    assert json.loads(res.stdout)["reports"][0]["suite"] == "linear"


def test_the_library_imports_neither_typer_nor_rich():
    code = ("import sys, mptrack, mptrack.tracking, mptrack.report, mptrack.experiments, mptrack.bench, mptrack.io\n"
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'typer', 'rich', 'click'}))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "[]", res.stdout + res.stderr
