"""mptrack.track, the Python face of ``mptrack track``: explicit keyword options documented in its
signature and numpydoc docstring, unknown and inapplicable options refused with an mptrack error (as the
command line refuses them), and ``report=PATH`` writing the page ``mptrack track --report`` writes."""

from __future__ import annotations

import doctest
import inspect
import json
import re
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import mptrack
import mptrack.tracking._pipeline as pipeline
from mptrack.errors import MptrackError, ParameterError
from mptrack.tracking import CELL_ONLY, FIX_ONLY, TrackOptions


@pytest.fixture(scope="module")
def logs():
    fixes = mptrack.simulate("gps", tracks=2, seed=4, duration_s=120.0)
    cellular = mptrack.simulate("urban-3bts", tracks=1, seed=3, duration_s=60.0)
    return fixes, cellular


def test_mptrack_track_is_the_documented_function():
    assert mptrack.track is pipeline.track
    params = inspect.signature(mptrack.track).parameters
    # every setting of TrackOptions is a keyword of its own, with its default None (or False) in the signature
    for name in FIX_ONLY + CELL_ONLY + ("gap_s",):
        assert name in params and params[name].kind is inspect.Parameter.KEYWORD_ONLY, name
        assert params[name].default in (None, False), name
    doc = inspect.getdoc(mptrack.track)
    for section in ("Parameters\n----------", "Returns\n-------", "Raises\n------", "Examples\n--------"):
        assert section in doc
    section = doc.split("Parameters\n----------\n")[1].split("\n\nReturns")[0]
    documented = {name for line in section.splitlines() if line and not line.startswith(" ")
                  for name in line.split(" :")[0].split(", ")}
    missing = [p for p in params if p not in ("data", "unknown") and p not in documented]
    assert not missing, f"not in the docstring's Parameters: {missing}"


def test_the_docstring_examples_run():
    runner = doctest.DocTestRunner()
    for test in doctest.DocTestFinder().find(pipeline.track, "track", globs={}):
        runner.run(test)
    assert runner.failures == 0 and runner.tries >= 4


@pytest.mark.parametrize("options", [{"method": "ukf"}, {"method": "nonsense"}, {"motion": "cv"}, {"r_km2": 5},
                                     {"path_loss": "free-space"}, {"q_km2": 0.1}, {"scan_interval_s": 2.0}])
def test_cellular_options_on_position_fixes_are_refused(logs, options):
    """The gated KF used to run without a word with these (the CLI refused them)."""
    fixes, _ = logs
    name = next(iter(options))
    with pytest.raises(ParameterError, match=rf"^{name}: applies to cellular measurements only: give the cell "
                                             r"table with cells="):
        mptrack.track(fixes, **options)


@pytest.mark.parametrize("options", [{"model": "cv"}, {"filter": "kf"}, {"smooth": True}, {"q": 1.0},
                                     {"sigma_m": 5.0}, {"noise": "file"}, {"gate_probability": 0.99}])
def test_position_fix_options_with_cells_are_refused(logs, options):
    _, cellular = logs
    name = next(iter(options))
    with pytest.raises(ParameterError, match=rf"^{name}: applies to position fixes, not to cellular"):
        mptrack.track(cellular, cells=cellular.attrs["cells"], **options)


def test_unknown_options_and_bad_values_are_mptrack_errors(logs):
    fixes, cellular = logs
    with pytest.raises(ParameterError, match="^metod: not an option of mptrack.track; did you mean method"):
        mptrack.track(fixes, metod="ekf")
    with pytest.raises(ParameterError, match="^gate: not an option .* did you mean gate_probability"):
        mptrack.track(fixes, gate=0.99)
    for options, match in (({"max_workers": 2}, "^max_workers: applies to executor="),
                           ({"client": object()}, "^client: applies to executor='dask'"),
                           ({"max_skip": "5"}, "^max_skip: applies to on_error='skip'"),
                           ({"smooth": "yes"}, "^smooth: expected True or False"),
                           ({"model": "cx"}, "^model: unknown motion model 'cx'")):
        with pytest.raises(MptrackError, match=match):
            mptrack.track(fixes, **options)
    with pytest.raises(MptrackError, match="^method: unknown cellular method 'ukf'"):
        mptrack.track(cellular, cells=cellular.attrs["cells"], method="ukf")
    # what is given applies: gate_probability=1 disables the gate (as --gate 1), a cellular method runs
    points = mptrack.track(fixes, gate_probability=1)
    assert not points["flag"].isin(["outlier", "reset", "manoeuvre"]).any()
    fcs = mptrack.track(cellular, cells=cellular.attrs["cells"], method="fcs", motion="cv", r_km2=0.1)
    assert fcs["method"].eq("FCS-cv").all()


def _page_data(path) -> dict:
    text = path.read_text()
    return json.loads(re.search(r"<script type='application/json' id='mptrack-data'>(.*?)</script>", text,
                                re.S).group(1))


def _quality(path) -> str:
    return re.search(r"<section id='quality-section'>(.*?)</section>", path.read_text(), re.S).group(1)


def test_report_writes_the_page_of_the_command_line(logs, tmp_path):
    fixes, _ = logs
    log = tmp_path / "log.csv"
    fixes.to_csv(log, index=False)
    ran = subprocess.run([sys.executable, "-m", "mptrack", "track", str(log), "--out", str(tmp_path / "o.parquet"),
                          "--report", str(tmp_path / "cli.html"), "--smooth", "-q"], capture_output=True, text=True)
    assert ran.returncode == 0 and ran.stdout == "" and ran.stderr == "", ran.stderr
    points = mptrack.track(log, smooth=True, report=tmp_path / "api.html")
    assert points.attrs["summary"]["report"] == str(tmp_path / "api.html")
    cli, api = _page_data(tmp_path / "cli.html"), _page_data(tmp_path / "api.html")
    assert api == cli  # the map, plots and table: the same data (the log's truth columns evaluated alike)
    assert api["payload"]["has_error"]
    assert _quality(tmp_path / "api.html") == _quality(tmp_path / "cli.html")
    # the report is refused where it would overwrite the input, and locked like any output
    with pytest.raises(MptrackError, match="report"):
        mptrack.track(log, report=log)
    assert log.read_text().startswith("track_id")


def test_options_equal_the_command_line_defaults(logs):
    """Options left out are TrackOptions' defaults: the same tracks as an explicit TrackOptions()."""
    fixes, _ = logs
    a = mptrack.track(fixes)
    b = pipeline.track(fixes, model="cv", filter="kf", noise="track", gate_probability=TrackOptions().gate_probability)
    pd.testing.assert_frame_equal(a, b)
    assert np.isfinite(a["east_m"]).all()
