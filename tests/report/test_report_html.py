"""The HTML report: one self-contained file (Leaflet inlined, nothing fetched), every track listed and
drawn as its own layer, time plots of one track at a time, captions that name only what is drawn, the
data-quality section, decimation of large tables; rendered by headless Chromium (offline) for 1 track,
3 tracks with truth and rejections, and 3000 tracks.

Screenshots are kept in $MPTRACK_TEST_ARTEFACTS (default: pytest's temporary directory, printed)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mptrack.report import PALETTE, write_report
from mptrack.report._page import asset
from mptrack.report._decimate import BREAK, MIN_PER_TRACK, ORDINARY, REJECTED, keep_mask, point_budget
from mptrack.report._payload import track_payload
from mptrack.io import read_output
from mptrack.tracking import evaluate_tracks, simulate, track_file

from _data import REAL_TRACES

CHROMIUM = Path("/usr/bin/chromium")
needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(), reason="headless render tests need Debian's chromium "
                                                                   "(apt-get install -y chromium)")


# ---------------------------------------------------------------- data

def synthetic_table(n_tracks: int, per: int, seed: int = 0, rejected: float = 0.01) -> pd.DataFrame:
    """A point table shaped like mptrack track's output (no tracking run: fast for many tracks), with a
    fraction ``rejected`` of the fixes rejected by the gate."""
    rng = np.random.default_rng(seed)
    n = n_tracks * per
    tid = np.repeat([f"dev{i:05d}" for i in range(n_tracks)], per)
    t = np.tile(np.arange(per, dtype=float) * 2.0, n_tracks)
    lat0 = np.repeat(45.0 + rng.uniform(-0.2, 0.2, n_tracks), per)
    lon0 = np.repeat(13.7 + rng.uniform(-0.3, 0.3, n_tracks), per)
    east = np.tile(np.arange(per) * 20.0, n_tracks) + rng.normal(0, 1, n)
    north = np.cumsum(rng.normal(0, 3, n))
    lat = lat0 + north / 111_320.0
    lon = lon0 + east / (111_320.0 * np.cos(np.radians(45.0)))
    flag = np.where(rng.random(n) < rejected, "outlier", "update").astype(object)
    flag[np.arange(n_tracks) * per] = "init"
    var = rng.uniform(4, 9, n)
    return pd.DataFrame({
        "track_id": tid, "t": t, "lat": lat, "lon": lon, "east_m": east, "north_m": north,
        "vel_east_mps": np.full(n, 10.0), "vel_north_mps": rng.normal(0, 1, n), "var_east_m2": var,
        "cov_en_m2": np.zeros(n), "var_north_m2": var, "ell_major_m": np.sqrt(var), "ell_minor_m": np.sqrt(var),
        "ell_azimuth_deg": np.zeros(n), "nis": rng.chisquare(2, n), "nis_dof": np.full(n, 2),
        "flag": flag, "gap": np.zeros(n, bool), "origin_lat": lat0, "origin_lon": lon0,
        "method": "KF-gated", "meas_lat": lat + rng.normal(0, 3e-5, n), "meas_lon": lon + rng.normal(0, 3e-5, n)})


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    """{"one": (path, ids), "three": ..., "many": ...}"""
    d = tmp_path_factory.mktemp("reports")
    out = {}
    # one real track, no truth
    run = track_file(REAL_TRACES["car"], d / "car.parquet")
    table = read_output(d / "car.parquet")
    summary, _ = evaluate_tracks(table)
    out["one"] = (write_report(table, d / "one.html", summary=summary, run=run, title="one track"),
                  sorted(summary["tracks"]))
    # three simulated tracks with truth, outliers and rows skipped
    log, _ = simulate("gps", 3, np.random.default_rng(5), duration_s=300, outlier_rate=0.05)
    log.to_csv(d / "sim.csv", index=False)
    with open(d / "sim.csv", "a") as fh:
        fh.write("sim0001,not a time,45.0,13.7,5.0,45.0,13.7,False\n")
    run = track_file(d / "sim.csv", d / "sim.parquet", on_error="skip")
    summary, table = evaluate_tracks(read_output(d / "sim.parquet"), log)
    out["three"] = (write_report(table, d / "three.html", summary=summary, run=run, title="three tracks"),
                    sorted(summary["tracks"]))
    # 3000 tracks
    table = synthetic_table(3000, 30)
    summary, _ = evaluate_tracks(table)
    out["many"] = (write_report(table, d / "many.html", summary=summary, title="3000 tracks"),
                   sorted(summary["tracks"]))
    return out


# ---------------------------------------------------------------- the file

class _Text(HTMLParser):
    def __init__(self):
        super().__init__()
        self.urls, self.scripts = [], 0

    def handle_starttag(self, tag, attrs):
        self.scripts += tag == "script"
        self.urls += [v for k, v in attrs if k in ("src", "href") and v]


def _data(path: Path) -> dict:
    text = path.read_text()
    m = re.search(r"<script type='application/json' id='mptrack-data'>(.*?)</script>", text, re.S)
    return json.loads(m.group(1))


def test_the_report_is_one_file_that_fetches_nothing(reports):
    path, _ = reports["one"]
    text = path.read_text()
    p = _Text()
    p.feed(text)
    assert not [u for u in p.urls if re.match(r"(https?:)?//", u)]  # no external script, style or image
    assert "Leaflet 1.9.4" in text or 'version="1.9.4"' in text  # the vendored library is inlined
    assert "L.map(" in text and p.scripts == 4  # error catcher, data, leaflet, report
    # the only network address in the page is the optional tile layer's (used when online)
    # (Leaflet's own text names bug trackers in comments), and the SVG namespace
    ours = text.replace(asset("leaflet.js"), "").replace(asset("leaflet.css"), "")
    assert len(ours) < len(text) - 100_000
    assert set(re.findall(r"https?://([a-z0-9.{}-]+)/", ours)) == {"tile.openstreetmap.org", "www.w3.org"}
    assert [p.name for p in path.parent.iterdir() if p.name.startswith(".")] == []


def test_every_track_is_in_the_data_and_the_table(reports):
    for key in ("one", "three", "many"):
        path, ids = reports[key]
        data = _data(path)
        assert sorted(t["id"] for t in data["payload"]["tracks"]) == ids
        assert sorted(r[0] for r in data["summary"]["rows"]) == ids  # all tracks, none cut off at 200
        assert data["summary"]["overall"][0] == "all"


def test_captions_name_only_what_is_drawn(reports):
    one = reports["one"][0].read_text()
    cap = re.search(r"id='map-caption'>(.*?)</p>", one).group(1)
    assert "truth" not in cap and "raw fixes (grey dots)" in cap
    assert ("rejected" in cap) == ("'rejected'" in json.dumps(_data(reports["one"][0])["kinds"]).replace('"', "'"))
    three = reports["three"][0].read_text()
    cap = re.search(r"id='map-caption'>(.*?)</p>", three).group(1)
    assert "truth (dashed black line)" in cap and "fixes rejected by the NIS gate (orange rings)" in cap
    assert "decimated" not in three.split("<section")[0]
    many = reports["many"][0].read_text()
    cap = re.search(r"id='map-caption'>(.*?)</p>", many).group(1)
    assert "truth" not in cap and "the 16 colours repeat" in cap


def test_data_quality_lists_skipped_rows_by_reason_and_left_out_records(reports, tmp_path):
    three = reports["three"][0].read_text()
    quality = three.split("id='quality-section'")[1].split("</section>")[0]
    assert "rows skipped by reason" in quality and "1 skipped" in quality
    assert re.search(r"fixes rejected by the NIS gate", quality) and "mean NIS" in quality
    # a GPX file with a track that has no time: the 358 points left out are reported
    run = track_file(REAL_TRACES["hike"], tmp_path / "h.parquet")
    table = read_output(tmp_path / "h.parquet")
    text = write_report(table, tmp_path / "h.html", summary=evaluate_tracks(table)[0], run=run).read_text()
    quality = text.split("id='quality-section'")[1].split("</section>")[0]
    assert "358" in quality and "records left out" in quality
    # each left-out record once: a count in the table, its detail under it, not again as a note
    assert quality.count("<td>GPX track without time stamps</td><td>358</td>") == 1
    assert quality.count("has no &lt;time&gt; in any of its 358 points") == 1
    assert "records left out:" not in quality and "note: " not in quality


def test_far_nis_gets_a_verdict_and_the_run_advice(tmp_path):
    table = synthetic_table(2, 50)
    table["nis"] = table["nis"] * 0.02  # far below its band
    summary, _ = evaluate_tracks(table)
    run = {"nis": {"advice": ["2 track(s) have a mean NIS far below its band: leave --sigma out"]}}
    text = write_report(table, tmp_path / "r.html", summary=summary, run=run).read_text()
    assert "below its band; far below" in text and "advice:</strong> 2 track(s)" in text
    table["nis"] = table["nis"] / 0.02
    summary = evaluate_tracks(table)[0]
    text = write_report(table, tmp_path / "r.html", summary=summary).read_text()
    assert summary["overall"]["nis_consistent"]
    assert "inside its band" in text and "advice:" not in text


# ---------------------------------------------------------------- decimation

def test_point_budget_and_keep_mask():
    counts = np.array([10, 1000, 5000])
    assert point_budget(counts, 10_000).tolist() == [10, 1000, 5000]  # fits: everything
    b = point_budget(counts, 600)
    assert b.tolist() == [10, 99, 499] and (b >= np.minimum(counts, MIN_PER_TRACK)).all()
    offsets = np.concatenate([[0], np.cumsum(counts)])
    kinds = np.full(offsets[-1], ORDINARY, np.int8)
    kinds[offsets[1]::5] = REJECTED  # a fifth of every track rejected
    kinds[[500, 4000]] = BREAK
    kinds[offsets[2] + 1:offsets[2] + 2001:2] = BREAK  # track 3: 1000 breaks, more than half its share
    keep = keep_mask(offsets, b, kinds)
    per = np.add.reduceat(keep, offsets[:-1])
    assert per[0] == 10 and (per[1:] <= b[1:] + 1).all() and (per[1:] >= 0.9 * b[1:]).all()  # the budget holds
    assert keep[500] and keep[offsets[1:] - 1].all() and keep[offsets[:-1]].all()  # breaks within half a share
    for lo, hi in zip(offsets[1:-1], offsets[2:]):
        k = kinds[lo:hi]
        drawn, total = np.bincount(k[keep[lo:hi]], minlength=3), np.bincount(k, minlength=3)
        # rejected fixes are thinned like the others: drawn in the proportion they occur (not all of them)
        assert 0 < drawn[REJECTED] < total[REJECTED]
        assert drawn[REJECTED] / drawn[:2].sum() == pytest.approx(total[REJECTED] / total[:2].sum(), abs=0.03)
    t3 = kinds[offsets[2]:] == BREAK
    assert keep[offsets[2]:][t3].sum() <= b[2] // 2 + 1  # breaks beyond half the share are thinned too


def test_payload_shares_the_budget_between_layers_and_counts_what_is_not_drawn():
    table = synthetic_table(4, 3000, seed=2, rejected=0.4)
    table.loc[table.index[::1000], "flag"] = "reset"
    p = track_payload(table, budget=2000)
    assert p["decimated"] and p["drawn"] <= 2000 + 4  # every layer within the budget (+ each track's last row)
    outliers = int((table["flag"] == "outlier").sum())
    assert p["totals"] == {"raw": 12000 - outliers, "rejected": outliers, "resets": 12, "gaps": 0}
    drawn_o = sum(tr["f"].count("o") for tr in p["tracks"])
    assert drawn_o / p["drawn"] == pytest.approx(outliers / len(table), abs=0.03)  # thinned alike
    assert sum(tr["f"].count("r") for tr in p["tracks"]) == 12  # resets (few): all drawn
    for tr in p["tracks"]:
        lat = np.cumsum(tr["y"]) / p["scale"]
        lon = np.cumsum(tr["x"]) / p["scale"]
        g = table[table["track_id"] == tr["id"]]
        assert lat[0] == pytest.approx(g["lat"].iloc[0], abs=1e-6) and lat[-1] == pytest.approx(g["lat"].iloc[-1],
                                                                                                  abs=1e-6)
        assert lon[-1] == pytest.approx(g["lon"].iloc[-1], abs=1e-6)
        assert np.cumsum(tr["t"])[-1] / 1000 == pytest.approx(g["t"].iloc[-1] - g["t"].iloc[0], abs=5e-4)


def test_layer_labels_and_caption_say_how_many_of_how_many_are_drawn(tmp_path):
    table = synthetic_table(4, 3000, seed=2, rejected=0.4)
    text = write_report(table, tmp_path / "r.html", summary=evaluate_tracks(table)[0], budget=2000).read_text()
    kinds = _data(tmp_path / "r.html")["kinds"]
    raw, rej = kinds["raw"], kinds["rejected"]
    assert raw["count"] < raw["total"] == int((table["flag"] != "outlier").sum())
    assert raw["text"] == f"{raw['count']:,} of {raw['total']:,} drawn".replace(",", "\u202f")
    assert rej["count"] < rej["total"] and rej["text"].endswith(" drawn")
    cap = re.search(r"id='map-caption'>(.*?)</p>", text).group(1)
    assert "shared by every layer" in cap and "rejected fixes are thinned alike" in cap
    assert f"fixes rejected by the NIS gate (orange rings): {rej['text']}" in cap


def test_payload_of_tracks_in_local_metres():
    table = synthetic_table(2, 10).assign(lat=np.nan, lon=np.nan, meas_lat=np.nan, meas_lon=np.nan,
                                          origin_lat=np.nan, origin_lon=np.nan)
    p = track_payload(table)
    assert not p["geo"] and p["scale"] == 100.0
    assert np.cumsum(p["tracks"][0]["x"])[-1] / 100 == pytest.approx(table["east_m"].iloc[9], abs=0.01)


# ---------------------------------------------------------------- Chromium

def _artefacts(tmp_path_factory) -> Path:
    d = Path(os.environ.get("MPTRACK_TEST_ARTEFACTS") or tmp_path_factory.getbasetemp() / "artefacts")
    d.mkdir(parents=True, exist_ok=True)
    return d


def _chromium(page: Path, user_dir: Path, *extra: str, timeout: int = 180) -> subprocess.CompletedProcess:
    cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--no-first-run", "--disable-component-update", "--disable-sync", f"--user-data-dir={user_dir}",
           # offline: every network request goes to a closed port
           "--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>",
           "--enable-logging=stderr", "--v=0", "--hide-scrollbars", "--window-size=1300,1700",
           "--virtual-time-budget=15000", *extra, page.as_uri()]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


class _Dom(HTMLParser):
    def __init__(self):
        super().__init__()
        self.listed, self.attrs, self.paths = [], {}, []
        self.plots = []  # per time plot: {"labels": y of each y-axis label, "values": y of each drawn value}
        self.swatches = []  # per legend swatch: its shapes (tag, stroke, fill)
        self._in_plots = False
        self._tick = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag in ("html", "body"):
            self.attrs.update({f"{tag}:{k}": v for k, v in a.items()})
        if tag == "li" and "data-track" in a:
            self.listed.append(a["data-track"])
        if tag == "path" and a.get("stroke") and a.get("d", "").startswith("M"):
            self.paths.append(a["d"])
            self.plots[-1]["values"] += [float(y) for y in re.findall(r"[ML][\d.]+ ([\d.]+)", a["d"])]
        if tag == "svg" and a.get("class") == "plot":
            self.plots.append({"title": a.get("aria-label"), "labels": [], "values": []})
        if tag == "text" and a.get("class") == "tick" and a.get("text-anchor") == "end":
            self.plots[-1]["labels"].append(float(a["y"]) - 4)  # the label's baseline is 4 px below its tick
            self._tick = self.plots[-1].setdefault("texts", [])
        if a.get("class") == "swatch-svg":
            self.swatches.append([])
        if tag in ("circle", "line", "ellipse") and self.swatches and not self.plots and a.get("stroke"):
            self.swatches[-1].append((tag, a.get("stroke"), a.get("fill")))
        if a.get("class", "").startswith("leaflet-control-scale-line"):
            self.attrs["scale"] = True
        if tag == "circle" and self.plots:
            self.plots[-1]["values"].append(float(a["cy"]))
        if a.get("id") == "page-info":
            self.attrs["page-info"] = True

    def handle_data(self, data):
        if self.attrs.get("page-info") is True:
            self.attrs["page-info"] = data
        if self._tick is not None:
            self._tick.append(data)
            self._tick = None


def _render(path: Path, tmp_path, artefacts: Path) -> _Dom:
    proc = _chromium(path, tmp_path / "ud", "--dump-dom")
    assert proc.returncode == 0, proc.stderr[-3000:]
    dom = _Dom()
    dom.feed(proc.stdout)
    assert "Uncaught" not in proc.stderr, [line for line in proc.stderr.splitlines() if "Uncaught" in line]
    shot = artefacts / f"{path.stem}.png"
    proc = _chromium(path, tmp_path / "ud", f"--screenshot={shot}")
    assert proc.returncode == 0 and shot.exists(), proc.stderr[-3000:]
    shutil.rmtree(tmp_path / "ud", ignore_errors=True)
    return dom


def _colour_fraction(png: Path, hex_colour: str) -> float:
    import matplotlib.image as mpimg

    img = mpimg.imread(png)[..., :3]
    want = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255.0
    return float(np.mean(np.all(np.abs(img - want) < 0.06, axis=-1)))


@needs_chromium
@pytest.mark.parametrize("key", ["one", "three", "many"])
def test_chromium_renders_every_track_offline_without_errors(reports, key, tmp_path, tmp_path_factory):
    path, ids = reports[key]
    artefacts = _artefacts(tmp_path_factory)
    dom = _render(path, tmp_path, artefacts)
    assert dom.attrs.get("body:data-ready") == "1", "the page's script did not finish"
    assert "html:data-js-errors" not in dom.attrs, dom.attrs.get("html:data-js-errors")
    assert sorted(dom.listed) == ids  # every track id is in the track list
    assert dom.attrs["body:data-track-layers"] == str(len(ids))  # one map layer per track
    pages = -(-len(ids) // 50)
    assert dom.attrs["page-info"] == f"page 1 of {pages} ({len(ids)} of {len(ids)} tracks)"
    # the time plots show the selected (first) track alone: each line has that track's drawn points
    first = next(t for t in _data(path)["payload"]["tracks"] if t["id"] == ids[0]) if key != "many" else \
        _data(path)["payload"]["tracks"][0]
    assert dom.paths and all(d.count("M") == 1 and d.count("L") == first["drawn"] - 1 for d in dom.paths[:2])
    # every value of every time plot lies between two labels of its y axis (none below the lowest one)
    assert dom.plots and all(len(p["labels"]) >= 2 for p in dom.plots), dom.plots
    for p in dom.plots:
        lo, hi = max(p["labels"]), min(p["labels"])  # SVG y grows downwards
        assert all(hi - 0.5 <= y <= lo + 0.5 for y in p["values"]), (p["title"], lo, hi, max(p["values"]))
    shot = artefacts / f"{path.stem}.png"
    assert _colour_fraction(shot, PALETTE[0]) > 0.0005  # the first track's colour is on screen
    print(f"screenshot: {shot}")


@needs_chromium
def test_the_colour_check_can_fail(tmp_path):
    blank = tmp_path / "blank.html"
    blank.write_text("<html><body><h1>nothing</h1></body></html>")
    proc = _chromium(blank, tmp_path / "ud", f"--screenshot={tmp_path / 'blank.png'}")
    assert proc.returncode == 0
    assert _colour_fraction(tmp_path / "blank.png", PALETTE[0]) == 0.0


def _report_in_a_fresh_process(tmp_path, n_tracks: int, per: int, budget: int) -> tuple[int, Path]:
    """(peak memory in KB, the page) of evaluating and writing the report of a synthetic table with 40 %
    of its fixes rejected, in a fresh process (ru_maxrss)."""
    page = tmp_path / "big.html"
    code = ("import resource, sys; sys.path[:0] = %r\n"
            "from test_report_html import synthetic_table\n"
            "from mptrack.tracking import evaluate_tracks\n"
            "from mptrack.report import write_report\n"
            "t = synthetic_table(%d, %d, rejected=0.4)\n"
            "write_report(t, %r, summary=evaluate_tracks(t)[0], budget=%d)\n"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n") % (
        [str(Path(__file__).parent), str(Path(__file__).parents[1])], n_tracks, per, str(page), budget)
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2] / "src"))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    return int(res.stdout.split()[-1]), page


def test_the_budget_holds_with_many_rejected_fixes(tmp_path):
    """10^5 points, 40 % of them rejected, a budget of 20 000 (the 10^6 test's proportions, a tenth of
    the size): the page stays under 2 MB, every layer within the budget."""
    _, page = _report_in_a_fresh_process(tmp_path, 300, 334, 20_000)
    size = page.stat().st_size
    assert size < 2_000_000, size  # 20 MB for 10^6 points, proportionally
    data = _data(page)
    p = data["payload"]
    assert p["decimated"] and p["drawn"] <= 20_000 + 300  # + each track's last row
    assert data["kinds"]["rejected"]["count"] <= 0.45 * p["drawn"]  # thinned alike, not all 40 000 drawn
    assert data["kinds"]["rejected"]["total"] == int(data["summary"]["overall"][2])
    assert len(data["summary"]["rows"]) == 300


@pytest.mark.slow
def test_a_million_point_report_is_small_and_stays_under_1_gb(tmp_path):
    """10^6 points in 3000 tracks, 40 % of the fixes rejected: the page is under 20 MB and writing it
    (evaluation included) peaks under 1 GB (measured in a fresh process: ru_maxrss)."""
    peak, page = _report_in_a_fresh_process(tmp_path, 3000, 334, 200_000)
    assert peak < 1_000_000  # KB
    size = page.stat().st_size
    assert 2_000_000 < size < 20_000_000
    data = _data(page)
    assert data["payload"]["decimated"] and len(data["summary"]["rows"]) == 3000
    assert data["payload"]["drawn"] <= 200_000 + 3000


# ---------------------------------------------------------------- what issue 30 saw on real data

def test_times_are_milliseconds_so_a_50_hz_trace_is_drawn_in_time_order(tmp_path):
    """Deciseconds put two or three 50 Hz fixes at one time: the speed plot zig-zagged."""
    log, _ = simulate("gps", 1, np.random.default_rng(1), duration_s=20.0, interval="0.02", outlier_rate=0.0)
    table = _tracked(log, tmp_path)
    payload = track_payload(table)
    steps = payload["tracks"][0]["t"][1:]
    assert set(steps) == {20}  # exact milliseconds
    assert np.cumsum(payload["tracks"][0]["t"])[-1] == round(1000 * (table["t"].iloc[-1] - table["t"].iloc[0]))


def _tracked(log: pd.DataFrame, tmp_path: Path) -> pd.DataFrame:
    log.to_csv(tmp_path / "log.csv", index=False)
    track_file(tmp_path / "log.csv", tmp_path / "t.parquet")
    return read_output(tmp_path / "t.parquet")


def _sort_and_duplicate_notes(tmp_path: Path) -> str:
    from pathlib import Path as P

    bad = P(__file__).parents[1] / "data" / "bad"
    texts = []
    for name in ("shuffled.csv", "duplicate-rows.csv"):
        run = track_file(bad / name, tmp_path / f"{name}.parquet")
        table = read_output(tmp_path / f"{name}.parquet")
        texts.append(write_report(table, tmp_path / f"{name}.html", summary=evaluate_tracks(table)[0],
                                  run=run).read_text().split("id='quality-section'")[1].split("</section>")[0])
    return "".join(texts)


def test_the_sort_and_duplicate_notes_appear_once(tmp_path):
    quality = _sort_and_duplicate_notes(tmp_path)
    assert quality.count("were not in (track, time) order and were sorted") == 1
    assert quality.count("rows out of time order") == 0
    assert quality.count("exact repeats of the row before them were dropped") == 1
    assert "duplicate fixes dropped" not in quality


def _layers_report(tmp_path: Path) -> Path:
    """A page with every kind of point layer: raw and rejected fixes, restarts and gaps (and ellipses)."""
    table = synthetic_table(2, 200, seed=4, rejected=0.05)
    table.loc[table.index[[50, 51, 250]], "flag"] = "reset"
    table.loc[table.index[[120, 330]], "gap"] = True
    return write_report(table, tmp_path / "layers.html", summary=evaluate_tracks(table)[0], title="layers")


def test_the_caption_describes_each_layer_as_the_legend_draws_it(tmp_path):
    from mptrack.report import LAYERS

    path = _layers_report(tmp_path)
    data = _data(path)
    assert data["layers"] == json.loads(json.dumps(LAYERS))  # the page draws from the one table
    cap = re.search(r"id='map-caption'>(.*?)</p>", path.read_text()).group(1)
    for kind in ("raw", "rejected", "resets", "gaps", "ellipses"):
        assert kind in data["kinds"], kind
        assert f"{LAYERS[kind]['label']} ({LAYERS[kind]['look']})" in cap, kind
    assert "white dots ringed in black" in cap and LAYERS["gaps"]["marker"]["fillColor"] == "#ffffff" \
        and LAYERS["gaps"]["marker"]["color"] == "#000000"
    assert "scale bar" in cap


@needs_chromium
def test_chromium_draws_the_legend_as_the_map_and_a_scale_bar(tmp_path, tmp_path_factory):
    from mptrack.report import LAYERS

    path = _layers_report(tmp_path)
    dom = _render(path, tmp_path, _artefacts(tmp_path_factory))
    assert "html:data-js-errors" not in dom.attrs, dom.attrs.get("html:data-js-errors")
    assert dom.attrs.get("scale") is True  # Leaflet's scale bar
    order = [k for k in LAYERS if k in _data(path)["kinds"]]
    assert len(dom.swatches) == len(order)
    for kind, shapes in zip(order, dom.swatches):
        tag, stroke, fill = shapes[0]
        style = LAYERS[kind].get("marker") or LAYERS[kind]["line"]
        assert stroke == style["color"], kind
        if "marker" in LAYERS[kind]:
            want = "none" if style.get("fill") is False else style.get("fillColor", style["color"])
            assert tag == "circle" and fill == want, kind


@needs_chromium
def test_chromium_nis_axis_is_readable_with_a_1000_km_outlier(tmp_path, tmp_path_factory):
    """A fix 1000 km off (NIS ~1e10): the NIS axis spans 14 decades; its labels overlapped."""
    log, _ = simulate("gps", 1, np.random.default_rng(7), duration_s=300.0, outlier_rate=0.0)
    log.loc[log.index[40], "lat"] += 1e6 / 111_320.0
    table = _tracked(log, tmp_path)
    assert table["nis"].max() > 1e9
    summary, table = evaluate_tracks(table)
    path = write_report(table, tmp_path / "outlier.html", summary=summary, title="1000 km outlier")
    dom = _render(path, tmp_path, _artefacts(tmp_path_factory))
    nis = next(p for p in dom.plots if p["title"].startswith("NIS"))
    ys = sorted(nis["labels"])
    assert 2 <= len(ys) <= 7 and min(np.diff(ys)) >= 14, ys  # px between labels, 11 px text
    assert all(len(t) <= 6 for t in nis["texts"]), nis["texts"]  # 10¹², not 1000000000000
    assert any("\u00b9" in t or "\u2070" in t for t in nis["texts"])
    lo, hi = max(nis["labels"]), min(nis["labels"])
    assert all(hi - 0.5 <= y <= lo + 0.5 for y in nis["values"])
