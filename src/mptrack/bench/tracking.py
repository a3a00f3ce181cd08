"""Benchmark suites of ``mptrack track`` (``mptrack bench --suite tracking --suite tracking-accuracy``).

* ``tracking``: end-to-end throughput (read, calibrate, filter, write Parquet) of position-fix logs,
  each case next to the I/O floor measured in the same run on the same tables: reading the input
  with ``pandas.read_parquet`` and writing the output with ``DataFrame.to_parquet``; and the peak
  memory of a run in a fresh process.
* ``tracking-accuracy``: with no flags (noise estimated) against the same filter given the true
  sigma and q (the oracle) and against the raw fixes, over a sweep of fix noise and motion, at
  irregular intervals of 0.5-30 s.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from . import register_suite
from ._timing import best_time

__all__ = ["tracking_suite", "tracking_accuracy_suite", "rmse_vs_truth"]


def _log(path: Path, tracks: int, per_track: int, seed: int = 1) -> int:
    """A simulated log of ``tracks`` x ~``per_track`` fixes (1-3 s apart, no accuracy column) as Parquet."""
    from ..tracking import Intervals, simulate

    log, _ = simulate("gps", tracks, np.random.default_rng(seed), duration_s=2.0 * per_track,
                      interval=Intervals.uniform(1.0, 3.0), accuracy_column=False)
    log.drop(columns=["true_lat", "true_lon", "is_outlier"]).to_parquet(path, index=False)
    return len(log)


def _peak_mib(path: Path, out: Path) -> float:
    """Peak resident memory (MiB) of a fresh process tracking ``path`` with the defaults: its VmHWM
    (ru_maxrss would include the forking parent's memory, which Linux keeps across exec)."""
    code = ("import sys; from mptrack.tracking import track_file; track_file(sys.argv[1], sys.argv[2]); "
            "print(next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1])")
    proc = subprocess.run([sys.executable, "-c", code, str(path), str(out)], capture_output=True, text=True,
                          check=True)
    return int(proc.stdout.split()[-1]) / 1024.0


@register_suite("tracking")
def tracking_suite(quick: bool) -> dict:
    from ..tracking import TrackOptions, simulate, track_file

    fixes = 100_000 if quick else 1_000_000
    repeats = 1 if quick else 2
    rows, notes = [], []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cases = {"long": (fixes // 200, 200), "short": (fixes // 10, 10)}
        paths = {k: tmp / f"{k}.parquet" for k in cases}
        counts = {k: _log(paths[k], *cases[k]) for k in cases}
        out = tmp / "out.parquet"
        track_file(paths["long"], out, options=TrackOptions(sigma_m=5.0, q=0.5))  # imports, numba caches
        for name, key, options in (
                ("given sigma, q", "long", TrackOptions(sigma_m=5.0, q=0.5)),
                ("given sigma, q + smoothing", "long", TrackOptions(sigma_m=5.0, q=0.5, smooth=True)),
                ("no flags (noise estimated)", "long", TrackOptions()),
                ("given sigma, q; tracks of 10 fixes", "short", TrackOptions(sigma_m=5.0, q=0.5)),
                ("no flags; tracks of 10 fixes", "short", TrackOptions())):
            seconds = best_time(lambda: track_file(paths[key], out, options=options), repeats)
            output = pd.read_parquet(out)
            floor = best_time(lambda: (pd.read_parquet(paths[key]), output.to_parquet(tmp / "floor.parquet")), repeats)
            n, tracks = counts[key], cases[key][0]
            rows.append([name, n, tracks, n / seconds, floor / seconds])
        seconds = best_time(lambda: simulate("gps", fixes // 150, np.random.default_rng(0)), repeats)
        rows.append(["simulate (library, gps)", fixes, fixes // 150, fixes / seconds, None])
        peak = _peak_mib(paths["long"], tmp / "peak.parquet")
    notes.append(f"peak resident memory of a fresh process tracking the {counts['long']:,}-fix log with no flags: "
                 f"{peak:.0f} MiB (goal 1 GiB for 10^6 fixes)")
    notes.append("x I/O floor = fixes/s over that of pandas.read_parquet(input) + DataFrame.to_parquet(output) "
                 "of the same tables, measured in the same run (goal >= 0.25 for given sigma, q)")
    notes.append("goals at 10^6 fixes: >= 300 k fixes/s given, >= 150 k/s estimating, smoothing <= 1.5x; tracks of "
                 "10 fixes >= 200 k/s; simulate 10^6 rows <= 5 s")
    return {"suite": "tracking", "title": "mptrack track end to end, Parquet in and out (fixes/s)",
            "columns": ["case", "fixes", "tracks", "fixes/s", "x I/O floor"], "rows": rows,
            "notes": notes}


def rmse_vs_truth(points: pd.DataFrame, log: pd.DataFrame) -> tuple[float, float]:
    """(RMSE of the estimates, RMSE of the raw fixes) against a simulated log's truth, in metres,
    over every fix (the truth matched by :func:`mptrack.tracking.attach_truth`)."""
    from ..tracking import attach_truth

    table = attach_truth(points, log)
    raw = np.hypot(table["meas_east_m"] - table["true_east_m"], table["meas_north_m"] - table["true_north_m"])
    return float(np.sqrt(np.mean(table["error_m"] ** 2))), float(np.sqrt(np.mean(raw ** 2)))


@register_suite("tracking-accuracy")
def tracking_accuracy_suite(quick: bool) -> dict:
    from ..tracking import Intervals, simulate, track

    tracks, duration = (5, 3000.0) if quick else (20, 6000.0)
    rows = []
    rng = np.random.default_rng(2024)
    for outliers in (0.0, 0.02):
        for sigma in (1.0, 5.0, 20.0, 50.0, 100.0):
            for q in (0.01, 0.5, 10.0):
                log, _ = simulate("gps", tracks, rng, duration_s=duration, interval=Intervals.uniform(0.5, 30.0),
                                  q=q, sigma_m=sigma, outlier_rate=outliers, accuracy_column=False)
                auto, raw = rmse_vs_truth(track(log), log)
                oracle, _ = rmse_vs_truth(track(log, sigma_m=sigma, q=q), log)
                auto_s, _ = rmse_vs_truth(track(log, smooth=True), log)
                oracle_s, _ = rmse_vs_truth(track(log, smooth=True, sigma_m=sigma, q=q), log)
                rows.append([f"{outliers:.0%}", sigma, q, raw, oracle, auto / oracle, auto_s / oracle_s, auto / raw,
                             auto_s / raw])
    table = np.array([r[3:] for r in rows], dtype=float)
    clean = np.array([r[0] == "0%" for r in rows])
    notes = [f"{tracks} tracks of ~{int(duration / 15.25)} fixes per cell; constant-velocity truth with process-noise "
             "density q (m^2/s^3), fix noise sigma (m), intervals uniform 0.5-30 s; RMSE over every fix",
             f"without outliers: tracked/oracle <= {table[clean, 2:4].max():.3f} (goal 1.1), tracked/raw <= "
             f"{table[clean, 4:6].max():.3f} (goal 1.0)",
             f"with 2 % outliers displaced 50-150 m: tracked/oracle <= {table[~clean, 2:4].max():.3f}; the oracle "
             f"itself is worse than the raw fixes in {int((table[~clean, 1] > table[~clean, 0]).sum())} cells "
             "(where the motion between fixes is less predictable than the outliers are large, an accepted outlier "
             "also moves the next estimates)"]
    return {"suite": "tracking-accuracy",
            "title": "No flags vs the oracle (true sigma, q) and vs the raw fixes (RMSE ratios)",
            "columns": ["outliers", "sigma m", "q", "raw RMSE m", "oracle RMSE m", "tracked/oracle",
                        "smoothed/oracle", "tracked/raw", "smoothed/raw"], "rows": rows, "notes": notes}
