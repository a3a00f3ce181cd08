"""A self-contained HTML report of a tracking run: PNG figures embedded as base64, no scripts,
no network, so it opens offline and can be mailed as one file.

Sections: the tracks on a lat/lon plot (measurements, estimates, truth if known,
rejected outliers), position uncertainty (and error, with truth) over time, the
NIS consistency plot with its 95 % chi-square band, and a summary table.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np
import pandas as pd
import scipy.stats

from .._io import atomic_path

__all__ = ["write_report", "TRACK_COLOR"]

#: Colour of the estimated tracks (the render test looks for it in a screenshot).
TRACK_COLOR = "#d62728"
_MAX_TRACKS_DRAWN = 25


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _elapsed(g: pd.DataFrame) -> np.ndarray:
    t = g["t"].to_numpy(float)
    return t - t[0]


def _fig_tracks(df: pd.DataFrame):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 6.0))
    geodetic = bool(np.isfinite(df["lat"].to_numpy(float)).any())  # else x/y input: local metres
    rejected_shown = False
    for i, (tid, g) in enumerate(df.groupby("track_id", sort=False)):
        if i >= _MAX_TRACKS_DRAWN:
            break
        first = i == 0
        if {"meas_east_m", "meas_north_m"} <= set(g.columns):
            ok = np.isfinite(g["meas_east_m"].to_numpy(float))
            me, mn = g["meas_east_m"].to_numpy(float)[ok], g["meas_north_m"].to_numpy(float)[ok]
            if geodetic:
                from ..io import LocalFrame

                mn, me = LocalFrame(g["origin_lat"].iloc[0], g["origin_lon"].iloc[0]).to_geodetic(me, mn)
            ax.plot(me, mn, ".", color="0.6", ms=3, label="measurements" if first else None)
            out = (g["flag"].to_numpy()[ok] == "outlier")
            if out.any():
                ax.plot(me[out], mn[out], "x", color="tab:orange", ms=6,
                        label=None if rejected_shown else "rejected (NIS gate)")
                rejected_shown = True
        truth_cols = ("true_lon", "true_lat") if geodetic else ("true_east_m", "true_north_m")
        if truth_cols[1] in g.columns and np.isfinite(g[truth_cols[1]].to_numpy(float)).any():
            known = np.isfinite(g[truth_cols[1]].to_numpy(float))
            ax.plot(g[truth_cols[0]][known], g[truth_cols[1]][known], "--", color="k", lw=1,
                    label="truth" if first else None)
        x, y = (g["lon"], g["lat"]) if geodetic else (g["east_m"], g["north_m"])
        ax.plot(x, y, "-", color=TRACK_COLOR, lw=2.2, label="estimate" if first else None)
    if geodetic:
        lat0 = float(np.nanmean(df["lat"]))
        ax.set_aspect(1.0 / max(math.cos(math.radians(lat0)), 1e-3))
        ax.set_xlabel("longitude (deg)")
        ax.set_ylabel("latitude (deg)")
    else:
        ax.set_aspect(1.0)
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
    ax.ticklabel_format(useOffset=False)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("Tracks")
    return fig


def _fig_uncertainty(df: pd.DataFrame):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    has_err = "error_m" in df.columns
    for i, (tid, g) in enumerate(df.groupby("track_id", sort=False)):
        if i >= _MAX_TRACKS_DRAWN:
            break
        s = np.sqrt(g["var_east_m2"].to_numpy(float) + g["var_north_m2"].to_numpy(float))
        ax.plot(_elapsed(g), s, color="tab:blue", lw=1, alpha=0.8, label="1-sigma position (m)" if i == 0 else None)
        if has_err:
            ax.plot(_elapsed(g), g["error_m"], color=TRACK_COLOR, lw=0.8, alpha=0.8,
                    label="error vs truth (m)" if i == 0 else None)
    ax.set_yscale("log")
    ax.set_xlabel("time since track start (s)")
    ax.set_ylabel("metres")
    ax.legend(fontsize=8)
    ax.set_title("Position uncertainty" + (" and error" if has_err else "") + " over time")
    return fig


def _fig_nis(df: pd.DataFrame):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    nis = df["nis"].to_numpy(float)
    dof = df["nis_dof"].to_numpy()
    ok = np.isfinite(nis) & (dof > 0)
    starts = df.groupby("track_id", sort=False)["t"].transform("first").to_numpy(float)
    el = df["t"].to_numpy(float) - starts
    outl = df["flag"].to_numpy() == "outlier"
    ax.plot(el[ok & ~outl], nis[ok & ~outl], ".", ms=3, color="tab:blue", label="NIS")
    if (ok & outl).any():
        ax.plot(el[ok & outl], nis[ok & outl], "x", ms=5, color="tab:orange", label="rejected")
    text = "no measurements"
    use = ok & ~outl  # the measurements the filter accepted
    if use.any():
        d = int(np.median(dof[use]))
        lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], d)
        ax.axhline(lo, color="k", ls=":", lw=1)
        ax.axhline(hi, color="k", ls=":", lw=1, label=f"95 % chi-square band ({d} dof)")
        inside = np.mean((nis[use] >= scipy.stats.chi2.ppf(0.025, dof[use]))
                         & (nis[use] <= scipy.stats.chi2.ppf(0.975, dof[use])))
        text = (f"accepted measurements: mean NIS {nis[use].mean():.2f} (expected {dof[use].mean():.2f}), "
                f"{100 * inside:.1f} % inside the 95 % band; {int((ok & outl).sum())} rejected by the gate")
        ax.set_yscale("log")
    ax.set_xlabel("time since track start (s)")
    ax.set_ylabel("NIS")
    ax.set_title("Innovation consistency (NIS)")
    ax.legend(fontsize=8, loc="upper right")
    return fig, text


def _fmt(v) -> str:
    if isinstance(v, float):
        return "—" if not math.isfinite(v) else f"{v:.4g}"
    return html.escape(str(v))


def _table(rows: dict[str, dict]) -> str:
    cols: list[str] = []
    for r in rows.values():
        cols += [c for c in r if c not in cols]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in ["track"] + cols)
    body = "".join("<tr><td>" + html.escape(str(k)) + "</td>" + "".join(f"<td>{_fmt(r.get(c, ''))}</td>"
                                                                        for c in cols) + "</tr>"
                   for k, r in rows.items())
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


_CSS = """body{font-family:sans-serif;max-width:60em;margin:1em auto;color:#222}
img{max-width:100%;border:1px solid #ddd}table{border-collapse:collapse;font-size:0.85em}
td,th{border:1px solid #ccc;padding:0.2em 0.5em;text-align:right}th{background:#f3f3f3}
.note{color:#555;font-size:0.9em}"""


def write_report(tracks: pd.DataFrame, path, *, summary: dict | None = None, title: str = "mptrack report",
                 notes: list[str] | None = None) -> Path:
    """Write the HTML report of ``tracks`` (a track table, with error columns if evaluated) atomically.

    summary: the dict of :func:`mptrack.tracking.evaluate_tracks` (per-track and overall rows);
    computed without truth if not given.
    """
    import matplotlib

    matplotlib.use("Agg")
    from ..tracking._evaluate import evaluate_tracks

    if summary is None:
        summary, _ = evaluate_tracks(tracks)
    fig_nis, nis_text = _fig_nis(tracks)
    images = [("tracks", "Tracks", "Estimates (red), measurements (grey), truth (dashed) and fixes rejected "
               "by the NIS gate (orange)", _png(_fig_tracks(tracks))),
              ("uncertainty", "Uncertainty over time", "1-sigma position uncertainty sqrt(var_e + var_n)"
               + (" and error against truth" if "error_m" in tracks.columns else ""), _png(_fig_uncertainty(tracks))),
              ("nis", "NIS consistency", nis_text, _png(fig_nis))]
    rows = {"all": summary["overall"], **dict(list(summary["tracks"].items())[:200])}
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
             f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>",
             f"<p class='note'>{len(summary['tracks'])} tracks, {len(tracks)} points; "
             f"methods: {html.escape(', '.join(map(str, pd.unique(tracks['method']))))}</p>"]
    for note in notes or []:
        parts.append(f"<p class='note'>{html.escape(note)}</p>")
    for key, heading, caption, data in images:
        parts.append(f"<h2>{html.escape(heading)}</h2><figure><img id='{key}' alt='{key}' "
                     f"src='data:image/png;base64,{data}'><figcaption>{html.escape(caption)}</figcaption></figure>")
    parts.append("<h2>Summary</h2>" + _table(rows) + "</body></html>\n")
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text("".join(parts), encoding="utf-8")
    return path
