"""G-NetTrack Pro logs read as they come (issue 32, item 6): the three raw logs of the real LTE walks in
../shared/data/cellular/gnettrack/, checked against the shipped conversion of the same lines
(measurements.csv / truth.csv, made by another program: its README), then tracked and evaluated by the
command line with no preprocessing."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from _data import shared_data
from _geolocation import distance_m

from mptrack.errors import DataError, ParameterError
from mptrack.io import FIXES, MEASUREMENTS, ReadOptions, ReadReport, read_cells, read_chunks
from mptrack.tracking import resolve_cells

LOGS = ("ixelle_1", "lln_1", "waha_1")
ZONE = ReadOptions(timezone="Europe/Brussels")


def _read(name: str, schema, read=ZONE, report=None) -> pd.DataFrame:
    path = shared_data("cellular", "gnettrack", f"{name}.txt")
    return pd.concat(list(read_chunks(path, schema, read=read, report=report)), ignore_index=True)


@pytest.fixture(scope="module")
def converted():
    m = pd.read_csv(shared_data("cellular", "measurements.csv"), dtype={"mnc": str})
    return m[m.track_id.isin(LOGS)]


def _first_of_each_second(m: pd.DataFrame) -> pd.DataFrame:
    """The conversion's scans, the first of each second of each log (as the reader keeps them)."""
    scans = m.drop_duplicates(["track_id", "record"])
    keep = scans.drop_duplicates(["track_id", "time"])[["track_id", "record"]]
    return m.merge(keep, on=["track_id", "record"])


@pytest.mark.parametrize("name", LOGS)
def test_positions_are_the_phones_gps_in_utc(converted, name):
    report = ReadReport()
    fixes = _read(name, FIXES, report=report)
    truth = _first_of_each_second(converted[converted.track_id == name]).drop_duplicates("record")
    assert len(fixes) == len(truth) and (fixes.track_id == name).all()
    assert (fixes.time.dt.strftime("%Y-%m-%dT%H:%M:%SZ").to_numpy() == truth.time.to_numpy()).all()
    np.testing.assert_allclose(fixes[["lat", "lon"]].to_numpy(), truth[["lat", "lon"]].to_numpy(), atol=1e-9)
    np.testing.assert_allclose(fixes.accuracy_m, truth.gps_accuracy_m)
    repeated = converted[converted.track_id == name].drop_duplicates("record").duplicated("time").sum()
    assert report.left_out.get("scan in the same second as the one before", 0) == repeated


@pytest.mark.parametrize("name", LOGS)
def test_cells_are_the_logged_serving_cell_and_its_neighbours(converted, name):
    rows = _read(name, MEASUREMENTS)
    conv = _first_of_each_second(converted[converted.track_id == name])
    serving, conv_serving = rows[rows.role == "serving"], conv[conv.role == "serving"]
    assert serving.cell_id.tolist() == conv_serving.cell_key_logged.tolist()
    np.testing.assert_array_equal(serving.rss_dbm, conv_serving.rsrp_dbm)
    fresh = conv_serving.ta_android.where(conv_serving.ta_android < 2**31 - 1)   # Android's fresh TA only
    np.testing.assert_array_equal(serving.ta, fresh)
    nbr = rows[rows.role == "neighbour"]
    conv_nbr = conv[(conv.role == "neighbour") & conv.rsrp_dbm.between(-160, 0)]
    assert nbr[["pci", "earfcn", "rss_dbm"]].to_numpy().tolist() == \
        conv_nbr[["pci", "earfcn", "rsrp_dbm"]].to_numpy(float).tolist()


def test_neighbours_resolve_by_pci_and_earfcn_as_the_conversion_did(converted, tmp_path):
    """With the channel in the table (cells_meta's earfcn joined to cells.csv) the neighbours identified are
    exactly the conversion's; with the OpenCelliD table alone (no channel: matched on the PCI) each one the
    conversion identified and this one too is identified the same (a PCI on two carriers of the site is
    ambiguous and left out; more are matched, to the one cell of their PCI: a table without channels cannot
    tell a site's carriers apart)."""
    cells_csv = shared_data("cellular", "cells.csv")
    meta = pd.read_csv(shared_data("cellular", "cells_meta.csv"))
    with_channel = tmp_path / "cells.csv"
    pd.read_csv(cells_csv).merge(meta[["cell", "earfcn"]], on="cell").to_csv(with_channel, index=False)
    for name in LOGS:
        rows = _read(name, MEASUREMENTS)
        conv = _first_of_each_second(converted[converted.track_id == name])
        conv = conv[conv.role.eq("serving") | conv.rsrp_dbm.between(-160, 0)].reset_index(drop=True)
        # the conversion keys the serving cells under 206-4 (the MNC 01 scans are the same cells)
        expected = conv.cell_id.fillna("").to_numpy()
        for table, complete in ((with_channel, True), (cells_csv, False)):
            report = ReadReport()
            got = resolve_cells(rows, read_cells(table), file=name, report=report)
            kept = rows.index.isin(got.index)
            ok = expected[kept] != ""
            assert (got.cell_id.to_numpy()[ok] == expected[kept][ok]).all(), (name, table)
            if complete:                                              # none the conversion identified is lost
                assert (expected[~kept] == "").all()
                assert (got.cell_id.to_numpy()[~ok] == rows.cell_id[kept].to_numpy()[~ok]).all()
                assert kept.sum() == (expected != "").sum() + (conv.role.eq("serving") & (expected == "")).sum()


def _cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mptrack", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


@pytest.mark.parametrize("name", LOGS)
def test_track_then_evaluate_a_raw_log(tmp_path, converted, name):
    """``mptrack track walk.txt --cells cells.csv`` then ``mptrack evaluate ... --truth walk.txt``: one point per
    scan at its time, every point paired with the phone's GPS fix, and no worse than placing the phone on its
    serving cell's site (the areas have one site each: the data's README)."""
    log = shared_data("cellular", "gnettrack", f"{name}.txt")
    cells = shared_data("cellular", "cells.csv")
    out = tmp_path / "track.csv"
    proc = _cli("track", log, "--cells", cells, "--timezone", "Europe/Brussels", "-o", out)
    assert proc.returncode == 0, proc.stderr
    proc = _cli("evaluate", out, "--truth", log, "--timezone", "Europe/Brussels", "--json")
    assert proc.returncode == 0, proc.stderr
    overall = json.loads(proc.stdout)["overall"]
    track = pd.read_csv(out)
    conv = _first_of_each_second(converted[(converted.track_id == name) & (converted.role == "serving")])
    assert len(track) == len(conv) == overall["points"] == overall["matched_points"], overall
    site = read_cells(cells).loc[conv.cell_id]
    err = distance_m(track.lat.to_numpy(), track.lon.to_numpy(), conv.lat.to_numpy(), conv.lon.to_numpy())
    on_site = distance_m(site.lat.to_numpy(), site.lon.to_numpy(), conv.lat.to_numpy(), conv.lon.to_numpy())
    assert np.median(err) <= np.median(on_site) + 1.0, (np.median(err), np.median(on_site))
    # without the zone both are read as UTC: still paired, the result the same
    proc = _cli("track", log, "--cells", cells, "-o", tmp_path / "utc.csv")
    assert proc.returncode == 0 and "read as UTC" in proc.stderr, proc.stderr
    np.testing.assert_allclose(pd.read_csv(tmp_path / "utc.csv")[["lat", "lon"]], track[["lat", "lon"]])
    # the zone given to one command and not the other: the refusal names the hour between them
    proc = _cli("evaluate", tmp_path / "utc.csv", "--truth", log, "--timezone", "Europe/Brussels")
    assert proc.returncode == 2 and "1 h before the estimates'" in proc.stderr and "--timezone" in proc.stderr, \
        proc.stderr


def test_the_converted_csv_is_tracked_as_it_comes(tmp_path):
    """measurements.csv as shipped (its README: RSRP in ``rsrp_dbm``, an empty ``cell_id`` where a neighbour
    matched no table cell, one invalid -205 dBm level), tracked as a new user would: RSRP is the level (the
    RSSI column beside it is not), neighbours without an id are resolved by PCI and channel as in a raw log
    or left out with a note -- no column options, no --max-skip; only the one bad level needs --on-error
    skip.  Every scan of the walks gets a point (16 repeat their second: the first is kept), the error the
    raw logs' path gives."""
    meas, cells, truth = (shared_data("cellular", f) for f in ("measurements.csv", "cells.csv", "truth.csv"))
    out = tmp_path / "walks.csv"
    proc = _cli("track", meas, "--cells", cells, "-o", out)
    assert proc.returncode == 2 and "row 1537, column 'rss_dbm': outside -160.0 .. 0.0 dBm: -205" in proc.stderr, \
        proc.stderr
    proc = _cli("track", meas, "--cells", cells, "--on-error", "skip", "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr
    read = json.loads(proc.stdout)["read"]
    assert read["skipped_by_reason"] == {"rss_dbm: outside -160.0 .. 0.0 dBm": 1}, read
    assert sum(read["left_out"].values()) > 0, read   # neighbours no table cell matches
    proc = _cli("evaluate", out, "--truth", truth, "--json")
    assert proc.returncode == 0, proc.stderr
    overall = json.loads(proc.stdout)["overall"]
    assert overall["points"] == overall["matched_points"] == 953 - 16, overall
    assert overall["rmse_m"] < 500.0, overall


def test_bad_logs_and_zones(tmp_path):
    head = shared_data("cellular", "gnettrack", "lln_1.txt").read_text().splitlines()
    bad = tmp_path / "bad.txt"
    bad.write_text("\n".join([head[0], head[1].replace("2025.12.12_12.44.15", "12/12/2025 12:44")]) + "\n")
    with pytest.raises(DataError, match=r"row 1.*Timestamp.*YYYY.MM.DD_HH.MM.SS"):
        _read_path(bad)
    empty = tmp_path / "empty.txt"
    empty.write_text(head[0] + "\n")
    with pytest.raises(DataError, match="no scan below the header"):
        _read_path(empty)
    with pytest.raises(ParameterError, match="timezone: unknown time zone 'Mars/Olympus'"):
        ReadOptions(timezone="Mars/Olympus")
    spring = tmp_path / "spring.txt"   # 02:30 does not exist in Brussels on 2025-03-30
    spring.write_text("\n".join([head[0], head[1].replace("2025.12.12_12.44.15", "2025.03.30_02.30.00")]) + "\n")
    with pytest.raises(DataError, match="does not exist or is ambiguous in Europe/Brussels"):
        _read_path(spring)
    proc = _cli("track", bad, "--cells", shared_data("cellular", "cells.csv"), "--timezone", "Mars/Olympus")
    assert proc.returncode == 2 and "--timezone" in proc.stderr, proc.stderr


def _read_path(path):
    return pd.concat(list(read_chunks(path, FIXES, read=ZONE)))
