"""One mean NIS and one count of restarts for one run, wherever they are printed: the command line
(text and --json), the track table (--track-summary), mptrack evaluate (text and --json) and the HTML
report (its verdict agrees with nis_consistent), on a real phone log (../shared/data/receivers)."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from mptrack.tracking import NIS_FLAGS, nis_sentence, nis_stats
from mptrack.tracking._consistency import flag_counts, nis_band, pooled_nis, restart_mask

from _data import shared_data


def mptrack(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mptrack", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


def test_nis_stats_and_band_by_hand():
    nis = np.array([np.nan, 1.0, 3.0, 50.0, 2.0, 7.0, np.nan])
    flags = np.array(["init", "update", "manoeuvre", "outlier", "update", "reset", "predicted"])
    s = nis_stats(nis, np.full(7, 2), flags)
    assert s["mean_nis"] == 2.0 and s["nis_fixes"] == 3 and s["nis_dof"] == 2.0  # update + manoeuvre only
    lo, hi = nis_band(3, 2.0)
    import scipy.stats

    assert lo == pytest.approx(scipy.stats.chi2.ppf(0.025, 6) / 3) and hi == pytest.approx(scipy.stats.chi2.ppf(0.975, 6) / 3)
    assert s["nis_consistent"] == (lo <= 2.0 <= hi)
    assert nis_sentence(s) == f"mean NIS 2 over 3 fixes (expected 2, 95 % band {lo:.4g}-{hi:.4g}): inside its band"
    assert NIS_FLAGS == ("update", "manoeuvre")
    # pooled over tracks = over all their fixes
    a, b = nis_stats(nis[:3], [2] * 3, flags[:3]), nis_stats(nis[3:], [2] * 4, flags[3:])
    p = pooled_nis([a["mean_nis"], b["mean_nis"]], [2, 2], [a["nis_fixes"], b["nis_fixes"]])
    assert p == pytest.approx(s)


def test_restarts_are_runs_of_reset_fixes_within_a_track():
    flags = np.array(["init", "reset", "reset", "update", "reset", "init", "reset", "update"])
    new = np.array([1, 0, 0, 0, 0, 1, 0, 0], bool)
    assert restart_mask(flags == "reset", new).tolist() == [0, 1, 0, 0, 1, 0, 1, 0]
    c = flag_counts(flags, [0, 5, 8])
    assert c["resets"].tolist() == [3, 1] and c["restarts"].tolist() == [2, 1] and c["updates"].tolist() == [1, 1]
    # a run of resets that continues across two tracks is two restarts
    assert flag_counts(np.array(["reset", "reset", "reset"]), [0, 2, 3])["restarts"].tolist() == [1, 1]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One run of a real phone log (bus journey, 2144 fixes), everything it can print."""
    d = tmp_path_factory.mktemp("one-nis")
    log = shared_data("receivers", "bus-304-to-UL.gpx")
    text = mptrack("track", log, "--out", d / "o.parquet", "--report", d / "r.html", "--track-summary", d / "t.csv")
    assert text.returncode == 0, text.stderr
    js = mptrack("track", log, "--out", d / "o.parquet", "--json")
    ev_text, ev_json = mptrack("evaluate", d / "o.parquet"), mptrack("evaluate", d / "o.parquet", "--json")
    assert js.returncode == ev_text.returncode == ev_json.returncode == 0, (js.stderr, ev_text.stderr)
    return {"text": text.stdout, "json": json.loads(js.stdout), "table": pd.read_csv(d / "t.csv"),
            "points": pd.read_parquet(d / "o.parquet"), "report": (d / "r.html").read_text(),
            "ev_text": ev_text.stdout, "ev_json": json.loads(ev_json.stdout)}


def _report_table(html: str) -> dict:
    data = json.loads(re.search(r"id='mptrack-data'>(.*?)</script>", html, re.S).group(1))["summary"]
    return dict(zip(data["columns"], data["overall"]))


def test_every_place_prints_the_same_mean_nis(run):
    points = run["points"]
    ours = nis_stats(points["nis"], points["nis_dof"], points["flag"])  # the definition, from the output
    assert ours["nis_fixes"] == points["flag"].isin(["update", "manoeuvre"]).sum()
    values = {"--json": run["json"]["nis"]["mean_nis"], "--json track_noise": run["json"]["track_noise"][0]["mean_nis"],
              "track table": run["table"]["mean_nis"].iloc[0], "evaluate --json": run["ev_json"]["overall"]["mean_nis"],
              "report table": _report_table(run["report"])["mean_nis"]}
    for where, value in values.items():
        assert value == pytest.approx(ours["mean_nis"], rel=1e-12), where
    sentence = nis_sentence(ours)
    assert sentence in run["text"] and sentence in run["ev_text"] and sentence in run["report"]
    assert run["text"].count("mean NIS") == run["ev_text"].count("mean NIS ") == 1
    # one verdict: the summary's nis_consistent is what every sentence says
    consistent = bool(run["table"]["nis_consistent"].iloc[0])
    assert consistent == run["json"]["nis"]["nis_consistent"] == run["ev_json"]["overall"]["nis_consistent"] \
        == _report_table(run["report"])["nis_consistent"] == ours["nis_consistent"]
    assert ("inside its band" in sentence) == consistent
    assert "inside the expected range" not in run["report"]


def test_every_place_counts_the_same_restarts(run):
    points = run["points"]
    resets = int((points["flag"] == "reset").sum())
    restarts = int(restart_mask(points["flag"].eq("reset").to_numpy(),
                                np.r_[True, points["track_id"].to_numpy()[1:] != points["track_id"].to_numpy()[:-1]]).sum())
    assert restarts <= resets
    assert run["json"]["restarts"] == run["table"]["restarts"].iloc[0] == run["ev_json"]["overall"]["restarts"] \
        == _report_table(run["report"])["restarts"] == restarts
    assert run["json"]["resets"] == run["table"]["resets"].iloc[0] == run["ev_json"]["overall"]["resets"] == resets
    assert f", {restarts} restart" in run["text"]
    assert f"{restarts} restart{'s' if restarts != 1 else ''} of the filter ({resets} fix" in run["report"]
