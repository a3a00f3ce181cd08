"""The HTML report: self-contained (offline), figures embedded, and rendered by headless Chromium."""

import base64
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from mptrack.report import TRACK_COLOR, write_report
from mptrack.tracking import evaluate_tracks, simulate, track_file
from mptrack.tracking._pipeline import read_output

CHROMIUM = Path("/usr/bin/chromium")
GPX = Path(__file__).parent / "data" / "around-visnjan-with-car.gpx"


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    log, _ = simulate("gps", 1, np.random.default_rng(3), along=GPX)
    log.to_parquet(d / "sim.parquet")
    track_file(d / "sim.parquet", d / "t.parquet")
    summary, table = evaluate_tracks(read_output(d / "t.parquet"), log)
    return write_report(table, d / "report.html", summary=summary, title="Visnjan drive")


def test_report_is_self_contained(report):
    text = report.read_text()
    assert "<script" not in text.lower()
    assert not re.search(r"(src|href)=['\"](https?:)?//", text)  # nothing fetched from the network
    images = re.findall(r"id='(\w+)' alt='\w+' src='data:image/png;base64,([^']+)'", text)
    assert [k for k, _ in images] == ["tracks", "uncertainty", "nis"]
    for _, data in images:
        assert base64.b64decode(data)[:8] == b"\x89PNG\r\n\x1a\n"
    assert "<h2>Summary</h2>" in text and "rmse_m" in text and "Visnjan drive" in text
    assert "inside the 95 % band" in text


def test_report_without_truth(tmp_path):
    track_file(GPX, tmp_path / "t.csv")
    path = write_report(read_output(tmp_path / "t.csv"), tmp_path / "r.html")
    text = path.read_text()
    assert "error against truth" not in text and "mean_nis" in text
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def _colour_fraction(png: Path, hex_colour: str) -> float:
    import matplotlib.image as mpimg

    img = mpimg.imread(png)[..., :3]
    want = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255.0
    return float(np.mean(np.all(np.abs(img - want) < 0.06, axis=-1)))


@pytest.mark.skipif(not CHROMIUM.exists(), reason="headless render test needs Debian's chromium "
                                                   "(apt-get install -y chromium); /usr/bin/chromium is absent")
def test_report_renders_the_tracks_in_headless_chromium(report, tmp_path):
    shot = tmp_path / "shot.png"
    cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={tmp_path / 'ud'}",
           "--hide-scrollbars", "--window-size=1000,900", f"--screenshot={shot}", report.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and shot.exists(), proc.stderr[-2000:]
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)[..., :3]
    assert img.std() > 0.05  # not a blank page
    assert _colour_fraction(shot, TRACK_COLOR) > 0.002  # the red estimated track is on screen
    # and the colour test can fail: an empty page has none of it
    blank = tmp_path / "blank.html"
    blank.write_text("<html><body><h1>nothing</h1></body></html>")
    cmd[-2], cmd[-1] = f"--screenshot={tmp_path / 'blank.png'}", blank.as_uri()
    subprocess.run(cmd, capture_output=True, timeout=120)
    assert _colour_fraction(tmp_path / "blank.png", TRACK_COLOR) == 0.0
    shutil.rmtree(tmp_path / "ud", ignore_errors=True)


def test_report_of_local_xy_tracks(tmp_path):
    import pandas as pd

    pd.DataFrame({"time": [0.0, 1.0, 2.5, 4.0], "x": [0.0, 10.0, 25.0, 41.0], "y": [0.0, 1.0, 0.0, 2.0]}).to_csv(
        tmp_path / "xy.csv", index=False)
    track_file(tmp_path / "xy.csv", tmp_path / "t.parquet")
    table = read_output(tmp_path / "t.parquet")
    assert table["lat"].isna().all() and np.isfinite(table["east_m"]).all()
    assert "<img id='tracks'" in write_report(table, tmp_path / "r.html").read_text()
