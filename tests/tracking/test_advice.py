"""Advice names only options that exist for that input: every option an advice line names is run, with
the value it suggests, as ``mptrack track`` on an input of that kind (position fixes, or cellular
measurements with --cells), and must be accepted; end to end, the advice that ``track`` and ``evaluate``
print on real runs is run the same way (``evaluate`` on an FCS output used to advise --model ca, which
``track --cells`` refuses; the cellular advice named --path-loss, which did not exist)."""

from __future__ import annotations

import json
import re

import pytest
from typer.testing import CliRunner

from mptrack.cli import app
from mptrack.tracking import TrackOptions
from mptrack.tracking._advice import nis_advice

from _data import REAL_TRACES

runner = CliRunner()

#: A value for an option that an advice names without one ("leave --sigma out", "a larger --range-sigma").
SAMPLE = {"--sigma": "5", "--q": "1", "--model": "ca", "--range-sigma": "900", "--path-loss": "cost231-hata"}


def suggestions(text: str) -> list[tuple[str, str]]:
    """(option, value) of every option an advice line names: the value it suggests ("try --model ca"),
    else a sample value (:data:`SAMPLE`); an option without a sample is an error of the test."""
    tried = re.findall(r"try (--[a-z][a-z-]*) ([^\s),;]+)", text)
    named = set(re.findall(r"--[a-z][a-z-]*", text)) - {o for o, _ in tried}
    return sorted(set(tried) | {(o, SAMPLE[o]) for o in named})


def test_suggestions_are_read_from_the_text():
    assert suggestions("x (try --model ca) or leave --sigma and --q out") == [
        ("--model", "ca"), ("--q", "1"), ("--sigma", "5")]
    assert suggestions("no option here") == []


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("advice")
    res = runner.invoke(app, ["simulate", "--scenario", "urban-3bts", "--tracks", "1", "--duration", "120",
                              "--seed", "3", "--out", str(d / "cell.csv"), "-q"])
    assert res.exit_code == 0, res.output
    return {"fixes": [str(REAL_TRACES["car"])], "cells": [str(d / "cell.csv"), "--cells", str(d / "cell.cells.csv")],
            "dir": d}


def _runs(inputs, kind: str, option: str, value: str) -> None:
    out = inputs["dir"] / f"{kind}{option}{value}.parquet"
    res = runner.invoke(app, ["track", *inputs[kind], "--out", str(out), "-q", option, value])
    assert res.exit_code == 0, f"the advice's {option} {value} on {kind}: {res.output}"


FIX_OPTIONS = [TrackOptions(), TrackOptions(model="ca"), TrackOptions(sigma_m=5.0), TrackOptions(q=1.0),
               TrackOptions(sigma_m=5.0, q=1.0), None]
CELL_OPTIONS = [TrackOptions(), TrackOptions(path_loss="cost231-hata"), TrackOptions(r_km2=0.01),
                TrackOptions(path_loss="free-space"), None]


@pytest.mark.parametrize("cellular", [False, True])
def test_every_option_an_advice_names_runs(inputs, cellular):
    kind = "cells" if cellular else "fixes"
    named = set()
    for options in CELL_OPTIONS if cellular else FIX_OPTIONS:
        for text in nis_advice(1, 1, options, cellular=cellular):
            named.update(suggestions(text))
    assert named, "the advice names no option at all"
    if not cellular:
        assert ("--model", "ca") in named and ("--sigma", "5") in named
    else:
        assert {o for o, _ in named} == {"--range-sigma", "--path-loss"}
    for option, value in sorted(named):
        _runs(inputs, kind, option, value)


def _advice(output: str) -> list[str]:
    return [line.removeprefix("advice: ") for line in output.splitlines() if line.startswith("advice: ")]


def test_the_advice_of_real_runs_and_evaluations_runs(inputs):
    """The runs that print advice: a cellular FCS run with too small a range noise (far above its band),
    its evaluation, and a GPS drive given too large a --sigma (far below)."""
    d = inputs["dir"]
    printed = {}
    res = runner.invoke(app, ["track", *inputs["cells"], "--method", "fcs", "--range-sigma", "30",
                              "--out", str(d / "fcs.parquet")])
    assert res.exit_code == 0, res.output
    printed["track --cells"] = ("cells", _advice(res.output))
    res = runner.invoke(app, ["evaluate", str(d / "fcs.parquet"), "--truth", inputs["cells"][0]])
    assert res.exit_code == 0, res.output
    printed["evaluate FCS"] = ("cells", _advice(res.output))
    res = runner.invoke(app, ["track", *inputs["fixes"], "--sigma", "50", "--out", str(d / "car.parquet"), "--json"])
    printed["track --sigma 50"] = ("fixes", json.loads(res.stdout)["nis"]["advice"])
    res = runner.invoke(app, ["evaluate", str(d / "car.parquet")])
    printed["evaluate car"] = ("fixes", _advice(res.output))
    for what, (kind, lines) in printed.items():
        assert lines, f"{what}: no advice printed"
        for line in lines:
            if kind == "cells":
                assert "--model" not in line and "--sigma" not in line, (what, line)
            for option, value in suggestions(line):
                _runs(inputs, kind, option, value)
