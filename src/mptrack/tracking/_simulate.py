"""Synthetic logs with truth: GPS fixes or cellular RSS scans, on simulated or real trajectories.

Scenarios (by name, :data:`SCENARIOS`):

* ``gps``        position fixes with Gaussian noise of ``sigma_m`` (5 m) per axis; a fraction
                 ``outlier_rate`` (2 %) are outliers displaced 50-150 m in a random direction
                 (``is_outlier``); an ``accuracy_m`` column (= ``sigma_m``) unless ``accuracy_column=False``.
                 Fix times by default: exponential intervals, mean 2 s, at least 0.2 s.
* ``urban-3bts`` three base stations on a 1 km circle around the track's centroid (120 deg apart); at each
                 scan each station's RSS = P_tx - L(d) + N(0, 4 dB) shadowing, L the COST-231 Walfisch-Ikegami
                 NLOS loss (h_base 30 m, DCS 1800 ARFCN 700 = 1842.8 MHz, P_tx 43 dBm); cell table in the
                 OpenCelliD layout.  Scan times by default: every second.

Truth is a constant-velocity trajectory, per axis x = (position, velocity) with white acceleration of density
``q`` (0.5 m^2/s^3), starting at the origin :data:`ORIGIN` with speed ``speed_mps`` (10 m/s) in a uniformly
random direction, sampled at times 0, then after each interval (:class:`Intervals`) up to ``duration_s``;
or, with ``along=``, the tracks of a real position-fix file (its time stamps and positions).

All tracks are simulated at once, as flat columns with track offsets (rows ``offsets[b]:offsets[b+1]`` are
track b), in chunks of whole tracks (about :data:`CHUNK_ROWS` fixes or scans) so that memory stays bounded:
:func:`simulate_chunks` yields the chunks, :func:`simulate` concatenates them.  The truth uses the exact
discretisation per interval dt, x_{k+1} = F(dt) x_k + w_k with F = [[1, dt], [0, 1]] and
w_k ~ N(0, q [[dt^3/3, dt^2/2], [dt^2/2, dt]]), drawn for all rows at once through the closed-form Cholesky
factor of that covariance; velocities and positions are then cumulative sums within each track.

Track i (0-based) starts at 2024-01-01T00:00:00Z + i hours; times are whole milliseconds and the truth is
at exactly those times.  Every random draw comes from the Generator passed in, so the result depends only
on its seed and the parameters.  (The numbers differ from the per-track implementation before the
vectorised one, except for ``along=`` files of one track, whose draws are unchanged.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np
import pandas as pd

from .._core.finiteness import derived_from
from .._core.validation import as_real, check_allocation, check_bool, check_int, check_positive, check_rng
from ..errors import DataError, ParameterError, UnknownNameError
from ..io import FIXES, ReadOptions, ReadReport, cell_key, iter_track_chunks
from ..io import enu_to_geodetic
from ..radio import arfcn_to_frequency, path_loss

__all__ = ["SCENARIOS", "simulate", "simulate_chunks", "Scenario", "Intervals", "ORIGIN", "CHUNK_ROWS"]

#: Origin of simulated tracks (Visnjan, Istria: where the bundled real trace is).
ORIGIN = (45.2735, 13.7142)
#: Rows per chunk of whole tracks (about; a track is never split).  Part of the definition of the
#: random stream: the draws of a chunk follow those of the previous one.
CHUNK_ROWS = 200_000
_EPOCH_MS = int(np.datetime64("2024-01-01T00:00:00", "ms").astype(np.int64))
_TRACK_SPACING_MS = 3_600_000


# --------------------------------------------------------------------------- parameters

_MAX_INTERVAL_S = 1e9


@dataclass(frozen=True)
class Intervals:
    """Distribution of the time between consecutive fixes (scans) of a simulated track, in seconds.

    ``Intervals.exponential(mean_s, min_s)``: max(X, min_s) with X exponential of mean ``mean_s``.
    ``Intervals.uniform(min_s, max_s)``: uniform on [min_s, max_s]; min_s == max_s is a regular grid.
    Intervals are rounded to whole milliseconds (the time resolution), so ``min_s >= 0.001``.
    :meth:`parse` reads the CLI form: ``exp:MEAN[:MIN]``, ``uniform:MIN:MAX`` (or ``MIN:MAX``), ``DT``.
    """

    kind: str
    min_s: float
    mean_s: float | None = None  # exponential
    max_s: float | None = None   # uniform

    def __post_init__(self) -> None:
        if self.kind not in ("exponential", "uniform"):
            raise UnknownNameError(f"interval: unknown kind {self.kind!r}; known: exponential, uniform")
        # intervals are whole milliseconds in int64: keep them far inside that range (1e9 s = 32 years)
        as_real("interval", self.min_s, low=0.001, high=_MAX_INTERVAL_S, unit="s")   # 0.001: the time resolution
        if self.kind == "exponential":
            check_positive("interval", as_real("interval", self.mean_s, high=_MAX_INTERVAL_S, unit="s"))
        elif as_real("interval", self.max_s, high=_MAX_INTERVAL_S, unit="s") < self.min_s:
            raise ParameterError(f"interval: expected min <= max, got {self.min_s} > {self.max_s}")

    @classmethod
    def exponential(cls, mean_s: float = 2.0, min_s: float = 0.2) -> "Intervals":
        return cls("exponential", min_s, mean_s=mean_s)

    @classmethod
    def uniform(cls, min_s: float, max_s: float) -> "Intervals":
        return cls("uniform", min_s, max_s=max_s)

    @classmethod
    def parse(cls, text: str) -> "Intervals":
        """``exp:MEAN[:MIN]`` (MIN default 0.2 s, or MEAN if smaller), ``uniform:MIN:MAX``, ``MIN:MAX`` or ``DT``."""
        kind, *rest = str(text).strip().split(":")
        if kind not in ("exp", "exponential", "uniform"):  # MIN:MAX or DT
            kind, rest = "uniform", [kind, *rest] if rest else [kind, kind]
        try:
            values = [float(v) for v in rest]
        except ValueError:
            values = []
        if kind != "uniform" and len(values) in (1, 2):
            return cls.exponential(values[0], values[1] if len(values) == 2 else min(0.2, values[0]))
        if kind == "uniform" and len(values) == 2:
            return cls.uniform(*values)
        raise ParameterError(f"interval: expected exp:MEAN[:MIN], uniform:MIN:MAX, MIN:MAX or DT (seconds), "
                             f"got {text!r}")

    def mean(self) -> float:
        """Mean interval (s)."""
        if self.kind == "uniform":
            return 0.5 * (self.min_s + self.max_s)
        return self.min_s + self.mean_s * float(np.exp(-self.min_s / self.mean_s))

    def draw_ms(self, rng: np.random.Generator, shape) -> np.ndarray:
        """Intervals in whole milliseconds (int64), ``shape`` of them (no draw for a regular grid)."""
        if self.kind == "exponential":
            s = np.maximum(rng.exponential(self.mean_s, size=shape), self.min_s)
        elif self.max_s > self.min_s:
            s = rng.uniform(self.min_s, self.max_s, size=shape)
        else:
            s = np.full(shape, self.min_s)
        return np.maximum(np.rint(s * 1e3), 1).astype(np.int64)


def _check_fraction(name: str, value) -> float:
    if check_positive(name, value, allow_zero=True) > 1.0:
        raise ParameterError(f"{name}: expected a fraction in [0, 1], got {value!r}")
    return float(value)


_CHECKS = {"sigma_m": lambda v: check_positive("sigma_m", v, allow_zero=True),
           "outlier_rate": lambda v: _check_fraction("outlier_rate", v),
           "accuracy_column": lambda v: check_bool("accuracy_column", v)}


# --------------------------------------------------------------------------- truth

@dataclass(frozen=True)
class _Truth:
    """A chunk of whole tracks as flat columns: rows offsets[b]:offsets[b+1] are track b."""

    index: np.ndarray     # (B,) track number in the whole run (0-based)
    track_id: np.ndarray  # (B,) object
    offsets: np.ndarray   # (B+1,) int64
    time_ms: np.ndarray   # (N,) int64, ms since 1970-01-01 UTC
    east: np.ndarray      # (N,) m, in the track's frame
    north: np.ndarray     # (N,) m
    lat0: np.ndarray      # (B,) origin of each track's frame (degrees)
    lon0: np.ndarray      # (B,)

    @property
    def row_track(self) -> np.ndarray:
        """(N,) position in the chunk of each row's track."""
        return np.repeat(np.arange(len(self.index)), np.diff(self.offsets))

    def geodetic(self, east, north, track=None) -> tuple[np.ndarray, np.ndarray]:
        """lat, lon of east/north points, each in the frame of its track (``track``: default each row's)."""
        track = self.row_track if track is None else track
        if (self.lat0 == self.lat0[0]).all() and (self.lon0 == self.lon0[0]).all():
            return enu_to_geodetic(east, north, self.lat0[0], self.lon0[0])  # one frame: no per-row origin
        return enu_to_geodetic(east, north, self.lat0[track], self.lon0[track])

    def columns(self, repeat: int = 1) -> dict:
        """track_id and time (UTC, ms) of each row, each repeated ``repeat`` times."""
        time = np.repeat(self.time_ms, repeat).astype("datetime64[ms]")
        return {"track_id": np.repeat(self.track_id[self.row_track], repeat),
                "time": pd.DatetimeIndex(time).tz_localize("UTC")}


def _segment_cumsum(x: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Cumulative sums along axis 0 restarting at each track's first row."""
    c = np.cumsum(x, axis=0)
    before = np.concatenate([np.zeros((1,) + x.shape[1:]), c[offsets[1:-1] - 1]])
    return c - np.repeat(before, np.diff(offsets), axis=0)


def cv_noise_factor(dt, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(l11, l21, l22): lower Cholesky factor of Q(dt) = q [[dt^3/3, dt^2/2], [dt^2/2, dt]] per interval,
    closed form: l11 = sqrt(q dt^3 / 3), l21 = sqrt(3 q dt) / 2, l22 = sqrt(q dt) / 2."""
    dt = np.asarray(dt, dtype=float)
    return np.sqrt(q * dt ** 3 / 3.0), np.sqrt(3.0 * q * dt) / 2.0, np.sqrt(q * dt) / 2.0


def cv_states(dt: np.ndarray, offsets: np.ndarray, v0: np.ndarray, z: np.ndarray, q: float):
    """Positions and velocities (N, axes) of constant-velocity tracks from given standard normals.

    dt (N,) interval before each row (0 at a track's first row, where the position is 0 and the
    velocity ``v0`` (B, axes)); z (N, axes, 2) standard normals.  Per axis and row, with
    w = L(dt) z (L = :func:`cv_noise_factor`): v_k = v_{k-1} + w_v, p_k = p_{k-1} + v_{k-1} dt + w_p,
    i.e. x_k = F(dt) x_{k-1} + w_k, computed as cumulative sums within each track.
    """
    l11, l21, l22 = (f[:, None] for f in cv_noise_factor(dt, q))
    w_p = l11 * z[..., 0]
    w_v = l21 * z[..., 0] + l22 * z[..., 1]
    v = np.repeat(v0, np.diff(offsets), axis=0) + _segment_cumsum(w_v, offsets)
    v_before = np.roll(v, 1, axis=0)  # the previous row's velocity (any value at a track's first row: dt = 0)
    return _segment_cumsum(v_before * dt[:, None] + w_p, offsets), v


def _fix_times_ms(rng, n_tracks: int, duration_ms: int, interval: Intervals) -> tuple[np.ndarray, np.ndarray]:
    """(offsets, times since each track's start in ms): 0, then after each interval while <= duration."""
    width = int(np.ceil(1.1 * duration_ms / 1e3 / interval.mean())) + 8  # intervals drawn per round
    blocks, last = [np.zeros((n_tracks, 1), dtype=np.int64)], np.zeros(n_tracks, dtype=np.int64)
    while (open_ := np.flatnonzero(last <= duration_ms)).size:  # rarely more than one round
        block = np.full((n_tracks, width), duration_ms + 1, dtype=np.int64)
        block[open_] = last[open_, None] + np.cumsum(interval.draw_ms(rng, (open_.size, width)), axis=1)
        blocks.append(block)
        last = block[:, -1]
    t = np.concatenate(blocks, axis=1)
    keep = t <= duration_ms  # a prefix of each row: times increase
    return np.concatenate([[0], np.cumsum(keep.sum(axis=1))]), t[keep]


def _simulated_truth(rng, first: int, n_tracks: int, duration_s: float, interval: Intervals, q: float,
                     speed_mps: float) -> _Truth:
    """Tracks first .. first + n_tracks - 1: fix times, then the CV truth at those times."""
    offsets, rel_ms = _fix_times_ms(rng, n_tracks, int(round(duration_s * 1e3)), interval)
    dt_ms = np.diff(rel_ms, prepend=0)
    dt_ms[offsets[:-1]] = 0
    heading = rng.uniform(0.0, 2.0 * np.pi, size=n_tracks)
    v0 = speed_mps * np.column_stack([np.sin(heading), np.cos(heading)])
    z = rng.standard_normal((len(rel_ms), 2, 2))
    pos, _ = cv_states(dt_ms / 1e3, offsets, v0, z, q)
    index = np.arange(first, first + n_tracks)
    start_ms = _EPOCH_MS + _TRACK_SPACING_MS * index
    return _Truth(index, np.strings.add("sim", np.strings.zfill((index + 1).astype(str), 4)).astype(object), offsets,
                  np.repeat(start_ms, np.diff(offsets)) + rel_ms, pos[:, 0], pos[:, 1],
                  np.full(n_tracks, ORIGIN[0]), np.full(n_tracks, ORIGIN[1]))


def _simulated_chunks(rng, tracks, duration_s, interval, q, speed_mps) -> Iterator[_Truth]:
    per_chunk = max(1, int(CHUNK_ROWS // (duration_s / interval.mean() + 1.0)))
    for first in range(0, tracks, per_chunk):
        yield _simulated_truth(rng, first, min(per_chunk, tracks - first), duration_s, interval, q, speed_mps)


def _along_chunks(path, read: ReadOptions, report: ReadReport | None) -> Iterator[_Truth]:
    """The tracks of a real position-fix file (lat/lon), each in the frame at its first fix, in chunks of
    whole tracks of at least CHUNK_ROWS rows (:func:`mptrack.io.iter_track_chunks` with ``read``, read whole
    and sorted: truth traces are small; its notes go to ``report``)."""
    from ._columns import FixTable

    first = 0
    for rows in iter_track_chunks(path, FIXES, chunk_rows=CHUNK_ROWS, sort=True, read=read, report=report):
        table = FixTable.from_frame(rows)
        if not table.geographic:
            raise DataError("along: the truth needs lat/lon columns", file=path, column="lat")
        lat0, lon0 = table.origin
        yield _Truth(np.arange(first, first + table.B), table.ids, table.offsets,
                     np.rint(table.t * 1e3).astype(np.int64), table.east, table.north, lat0, lon0)
        first += table.B
    if not first:
        raise DataError("along: no tracks in the file", file=path)


# --------------------------------------------------------------------------- scenarios

def _gps(rng, truth: _Truth, *, sigma_m: float, outlier_rate: float, accuracy_column: bool):
    n = len(truth.east)
    z = np.column_stack([truth.east, truth.north]) + rng.normal(0.0, sigma_m, size=(n, 2))
    out = rng.random(n) < outlier_rate
    ang = rng.uniform(0, 2 * np.pi, size=n)
    dist = rng.uniform(50.0, 150.0, size=n)
    z[out] += np.column_stack([np.sin(ang[out]), np.cos(ang[out])]) * dist[out, None]
    lat, lon = truth.geodetic(z[:, 0], z[:, 1])
    tlat, tlon = truth.geodetic(truth.east, truth.north)
    accuracy = {"accuracy_m": np.full(n, sigma_m)} if accuracy_column else {}
    return pd.DataFrame({**truth.columns(), "lat": lat, "lon": lon, **accuracy, "true_lat": tlat,
                         "true_lon": tlon, "is_outlier": out}), None


def _urban_3bts(rng, truth: _Truth, radius_m: float = 1000.0, shadowing_db: float = 4.0, power_dbm: float = 43.0,
                height_m: float = 30.0, arfcn: int = 700):
    frequency_mhz = float(arfcn_to_frequency(arfcn, "DCS1800"))
    starts, counts = truth.offsets[:-1], np.diff(truth.offsets)
    xy = np.column_stack([truth.east, truth.north])
    centre = np.add.reduceat(xy, starts, axis=0) / counts[:, None]
    ang = rng.uniform(0, 2 * np.pi, size=len(starts))[:, None] + np.array([0.0, 2.0, 4.0]) * np.pi / 3
    st = centre[:, None, :] + radius_m * np.stack([np.sin(ang), np.cos(ang)], axis=-1)  # (B, 3, 2)
    track = np.arange(len(starts))[:, None].repeat(3, axis=1)
    slat, slon = truth.geodetic(st[..., 0], st[..., 1], track=track)
    area = np.repeat(100 + truth.index, 3)
    cell = (10 * truth.index[:, None] + np.arange(1, 4)).ravel()
    ids = cell_key(np.full(cell.size, 262), np.ones(cell.size, int), area, cell).to_numpy(dtype=object)
    b = truth.row_track
    d_km = np.linalg.norm(xy[:, None, :] - st[b], axis=-1) / 1e3  # (N, 3)
    loss = path_loss(np.clip(d_km, 0.02, 5.0), "cost231-wi-nlos", frequency_mhz=frequency_mhz,
                     h_base_m=height_m, on_invalid="ignore")
    rss = power_dbm - loss + rng.normal(0.0, shadowing_db, size=loss.shape)
    tlat, tlon = truth.geodetic(truth.east, truth.north)
    log = pd.DataFrame({**truth.columns(repeat=3), "cell_id": ids.reshape(-1, 3)[b].ravel(), "rss_dbm": rss.ravel(),
                        "true_lat": np.repeat(tlat, 3), "true_lon": np.repeat(tlon, 3),
                        "true_range_m": d_km.ravel() * 1e3})
    m = cell.size
    cells = pd.DataFrame({"radio": "GSM", "mcc": np.full(m, 262), "net": np.ones(m, int), "area": area, "cell": cell,
                          "unit": 0, "lon": slon.ravel(), "lat": slat.ravel(), "range": 3000, "samples": 1,
                          "changeable": 1, "created": 0, "updated": 0, "averageSignal": 0, "height_m": height_m,
                          "power_dbm": power_dbm, "arfcn": arfcn})
    return log, cells


@dataclass(frozen=True)
class Scenario:
    """A named scenario: ``run(rng, truth chunk, **options)`` -> (log, cell table or None); ``interval`` the
    default times of simulated truth; ``options`` the scenario's measurement options and their defaults."""

    name: str
    description: str
    run: Callable
    interval: Intervals
    options: dict


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("gps", "GPS fixes at irregular times, 5 m noise, 2 % outliers", _gps, Intervals.exponential(2.0, 0.2),
             {"sigma_m": 5.0, "outlier_rate": 0.02, "accuracy_column": True}),
    Scenario("urban-3bts", "RSS from 3 base stations (COST-231 WI NLOS, 4 dB shadowing), 1 s scans",
             _urban_3bts, Intervals.uniform(1.0, 1.0), {}),
)}


# --------------------------------------------------------------------------- public functions

def simulate_chunks(scenario: str, tracks: int, rng: np.random.Generator, *, duration_s: float = 300.0,
                    along=None, interval: Intervals | str | None = None, q: float = 0.5, speed_mps: float = 10.0,
                    sigma_m: float | None = None, outlier_rate: float | None = None,
                    accuracy_column: bool | None = None, read: ReadOptions = ReadOptions(),
                    report: ReadReport | None = None) -> Iterator[tuple[pd.DataFrame, pd.DataFrame | None]]:
    """A simulated log in chunks of whole tracks (memory bounded by the chunk); the arguments are checked
    before the first chunk.

    Parameters
    ----------
    scenario : str
        A key of :data:`SCENARIOS`: "gps" (fixes at irregular times) or "urban-3bts" (RSS from three base
        stations).
    tracks : int
        Number of tracks.
    rng : numpy.random.Generator
    duration_s : float, optional
        Length of each track (s).
    along : str or path-like, optional
        A position-fix file whose tracks are the truth (read like ``track``'s input); ignores the
        simulated-truth options.
    interval : Intervals or str, optional
        The times between fixes (an :class:`Intervals` or its text form; default the scenario's).
    q : float, optional
        Process-noise density of the simulated truth (m^2/s^3).
    speed_mps : float, optional
        Mean speed of the simulated truth (m/s).
    sigma_m, outlier_rate, accuracy_column : optional
        Options of the "gps" scenario (fix noise (m), outlier fraction, whether to write accuracy_m;
        None: its default); giving one to another scenario is a ParameterError.
    read : ReadOptions, optional
        How ``along`` is read.
    report : ReadReport, optional
        Receives how ``along`` was read.

    Yields
    ------
    log : pandas.DataFrame
    cells : pandas.DataFrame or None
    """
    return _chunks(scenario, tracks, rng, duration_s=duration_s, along=along, interval=interval, q=q,
                   speed_mps=speed_mps, sigma_m=sigma_m, outlier_rate=outlier_rate, accuracy_column=accuracy_column,
                   read=read, report=report, whole=False)


#: Bytes a simulated row takes, its columns and the intermediate arrays (the memory estimate).
_ROW_BYTES = 256


def _chunks(scenario, tracks, rng, *, duration_s, along, interval, q, speed_mps, sigma_m, outlier_rate,
            accuracy_column, read, report, whole: bool):
    """:func:`simulate_chunks`; ``whole``: the chunks will be held at once (by :func:`simulate`), so their
    total size is checked against the memory limit, not only one track's."""
    if scenario not in SCENARIOS:
        raise UnknownNameError(f"scenario: unknown name {scenario!r}; known: {', '.join(SCENARIOS)}")
    sc = SCENARIOS[scenario]
    given = {"sigma_m": sigma_m, "outlier_rate": outlier_rate, "accuracy_column": accuracy_column}
    options = dict(sc.options)
    for name, value in given.items():
        if value is not None:
            if name not in options:
                raise ParameterError(f"{name}: not an option of scenario {scenario!r} "
                                     f"(its options: {', '.join(options) or 'none'})")
            options[name] = _CHECKS[name](value)
    if along is not None:
        truths = _along_chunks(along, read, report)
    else:
        tracks = check_int("tracks", tracks, minimum=1)
        duration_s = check_positive("duration_s", duration_s)
        q = check_positive("q", q, allow_zero=True)
        speed_mps = check_positive("speed_mps", speed_mps, allow_zero=True)
        interval = sc.interval if interval is None else \
            interval if isinstance(interval, Intervals) else Intervals.parse(interval)
        check_rng(rng)
        row_bytes = _ROW_BYTES * (3 if scenario == "urban-3bts" else 1)
        per_track = (duration_s / interval.mean() + 1.0) * row_bytes      # a chunk holds at least one track
        check_allocation("duration_s", duration_s, per_track)
        if whole:
            check_allocation("tracks", tracks, tracks * per_track)
        truths = _simulated_chunks(rng, tracks, duration_s, interval, q, speed_mps)
        return _named_runs(sc, rng, truths, options, dict(q=q, speed_mps=speed_mps, duration_s=duration_s))
    return (sc.run(rng, truth, **options) for truth in truths)


def _named_runs(sc, rng, truths, options: dict, given: dict):
    """The scenario's chunks of simulated truth; an error about a quantity derived from the simulation
    (a position beyond the ellipsoid for q = 1e30) names the argument of largest magnitude."""
    with derived_from(**given):
        yield from (sc.run(rng, truth, **options) for truth in truths)


def simulate(scenario: str, tracks: int, rng: np.random.Generator, *, duration_s: float = 300.0, along=None,
             interval: Intervals | str | None = None, q: float = 0.5, speed_mps: float = 10.0,
             sigma_m: float | None = None, outlier_rate: float | None = None,
             accuracy_column: bool | None = None, read: ReadOptions = ReadOptions(),
             report: ReadReport | None = None) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """A simulated log with truth columns, in one table.

    Parameters
    ----------
    scenario : str
        A key of :data:`SCENARIOS`: "gps" (fixes at irregular times) or "urban-3bts" (RSS from three base
        stations).
    tracks : int
        Number of tracks.
    rng : numpy.random.Generator
    duration_s : float, optional
        Length of each track (s).
    along : str or path-like, optional
        A position-fix file whose tracks are the truth (read like ``track``'s input); ignores the
        simulated-truth options.
    interval : Intervals or str, optional
        The times between fixes (an :class:`Intervals` or its text form; default the scenario's).
    q : float, optional
        Process-noise density of the simulated truth (m^2/s^3).
    speed_mps : float, optional
        Mean speed of the simulated truth (m/s).
    sigma_m, outlier_rate, accuracy_column : optional
        Options of the "gps" scenario (fix noise (m), outlier fraction, whether to write accuracy_m;
        None: its default); giving one to another scenario is a ParameterError.
    read : ReadOptions, optional
        How ``along`` is read.
    report : ReadReport, optional
        Receives how ``along`` was read.

    Returns
    -------
    log : pandas.DataFrame
        The measurements with ``true_*`` columns.
    cells : pandas.DataFrame or None
        The cell table of a cellular scenario.

    Raises
    ------
    ResourceError
        The log would exceed the memory limit (use :func:`simulate_chunks`).

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack.tracking import simulate
    >>> log, cells = simulate("gps", 2, np.random.default_rng(0), duration_s=60)
    >>> sorted(log["track_id"].unique()), cells is None
    (['sim0001', 'sim0002'], True)
    """
    chunks = _chunks(scenario, tracks, rng, duration_s=duration_s, along=along, interval=interval, q=q,
                     speed_mps=speed_mps, sigma_m=sigma_m, outlier_rate=outlier_rate,
                     accuracy_column=accuracy_column, read=read, report=report, whole=True)
    logs, cells = zip(*chunks)
    return pd.concat(logs, ignore_index=True), None if cells[0] is None else pd.concat(cells, ignore_index=True)
