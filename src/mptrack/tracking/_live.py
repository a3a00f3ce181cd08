"""The tracking engine advanced fix by fix for many devices at once: the filter of ``mptrack serve``.

:class:`LiveTracks` keeps one row per track (a device) in flat arrays -- the engine's filter state
(:mod:`._state`), the track's local frame (its first fix), its noise parameters and its last fix and
estimate -- and advances any subset of tracks with their new fixes in one call of a compiled kernel
that converts the fixes to each track's frame, steps the engine's per-track filter
(:func:`._track_filter.advance_track`) on the stored state in place and converts the estimates back
(a server's batch of a few dozen fixes spent more than half of its time in the ~60 array calls
around the engine's kernel before).  It is the gated filter of ``mptrack track`` (same model,
gating, manoeuvre, outlier and restart logic, flags): a track advanced piece by piece ends where one
run over all its fixes ends.

Noise.  A new track starts from what its first fix says: with an accuracy, fix variance
c * accuracy^2 with c the population's current accuracy scale (1 until tracks are calibrated);
without one, c = the population's current sigma^2 (``mptrack track``'s default, 5 m, until
then).  The noise of tracks is re-estimated from their recent fixes by the maximum likelihood of
``mptrack track`` (:mod:`._noise`), and the population values follow the medians of the calibrated tracks.
"""

from __future__ import annotations

import math
import struct

import numba as nb
import numpy as np
import pandas as pd

from ..errors import ParameterError, ShapeError
from ..io import enu_to_geodetic
from .._core.geodesy import enu_row, geodetic_row, origin_terms
from ._chain import SEQ, transition, work
from ._columns import FixTable
from ._state import ST_PENDING, ST_STREAK, STREAK_CAP, state_from_bytes, state_layout, state_order, states_to_bytes
from ._fix_error import SLOW_TAU_S, slow_variance
from ._track_filter import advance_track
from ._fixes import TrackOptions
from ._noise import estimate_noise as _estimate
from ._noise import fix_weights
from ._output import ellipse
from ._run import noise_spec
from ._registry import DEFAULT_SIGMA_M, MODELS, get_model

__all__ = ["LiveTracks", "ESTIMATE_FIELDS"]

#: The per-fix estimate :meth:`LiveTracks.advance` returns (and each track's last, :meth:`LiveTracks.summaries`):
#: position (degrees), east/north covariance (m^2), east/north velocity (m/s), NIS and flag (index into FLAGS).
ESTIMATE_FIELDS = ("lat", "lon", "var_e", "cov_en", "var_n", "vel_e", "vel_n", "nis", "flag")
# per-track scalars besides the engine state, in the order they are stored
_TRACK_FIELDS = ("lat0", "lon0", "c", "q", "mode", "w_fill", "t_last", "raw_lat", "raw_lon") + ESTIMATE_FIELDS
_LAT0, _LON0, _C, _Q, _MODE, _W_FILL, _T, _RAW_LAT, _RAW_LON = range(9)
_EST = 9
UNSET, ACCURACY, SIGMA = 0, 1, 2   # a track's fix-noise mode: not started, c scales accuracy^2, c = sigma^2
_BLOB = struct.Struct("<4sHH")     # magic, layout version, number of track scalars
# version 2: the engine's coasting state and run buffer only while the track has a manoeuvre candidate
# pending or is in a run (the engine reads them only then; they are zeros otherwise): a cv state is 404
# bytes instead of 1,060.  Version 1 (always whole) is read as well.
_MAGIC, _VERSION = b"MPLT", 2


class LiveTracks:
    """Filter states of many tracks, advanced fix by fix (see the module doc).

    options   the settings of ``mptrack track`` that apply (model, q, sigma_m, gate_probability)
    """

    def __init__(self, options: TrackOptions = TrackOptions()):
        if not isinstance(options, TrackOptions):
            raise ParameterError(f"options: expected TrackOptions, got {type(options).__name__}")
        self.options = options
        self.spec = noise_spec(options)
        self.order = self.spec.order
        self.model = get_model(options.model)
        # the engine's state row of each track (:mod:`._state`) in two parts: the filter's state for every
        # track (240 of 896 bytes a row for cv); the coasting state, the candidate's fix and the buffer of
        # the run of rejected fixes only for the tracks with a manoeuvre candidate pending or in a run (a
        # pool of rows, _slot[track] its row or -1; the engine reads them only then): a server's 10^6
        # devices, few of them pending or in a run at once, hold a quarter of the memory
        layout = state_layout.py_func(self.order + 1)
        self._split, size = layout[2], layout[-1]
        self._head = np.zeros((0, self._split))
        self._slot = np.zeros(0, np.int32)
        self._runs = np.zeros((0, size - self._split))
        self._free: list[int] = []
        self._track = np.zeros((0, len(_TRACK_FIELDS)))
        self.n = 0
        # what every stored state of this model starts with: the track header of each layout, the engine's
        # header (see states_bytes)
        self._layouts = np.array([np.frombuffer(_BLOB.pack(_MAGIC, v, len(_TRACK_FIELDS)), np.uint8)
                                  for v in (1, _VERSION)])
        self._engine_head = states_to_bytes(np.zeros((1, size)), self.order)[0, :-8 * size].copy()
        # a stored state's length: without the run's part, and whole
        head = _BLOB.size + 8 * len(_TRACK_FIELDS) + self._engine_head.size
        self._stored_sizes = (head + 8 * self._split, head + 8 * size)
        # the population's current noise: accuracy scale, sigma^2 (tracks without accuracy), q
        self.population = {"c_accuracy": 1.0, "c_sigma": (options.sigma_m or DEFAULT_SIGMA_M) ** 2,
                           "q": options.q if options.q is not None else self.model.default_q}

    # ---- tracks -----------------------------------------------------------------------------------
    def add(self, count: int = 1) -> np.ndarray:
        """Add ``count`` empty tracks; returns their indices."""
        first = self.n
        need = first + int(count)
        if need > len(self._head):
            size = max(need, 2 * len(self._head), 1024)
            # rows past ``need`` are written when tracks are added: left untouched, their pages take no memory
            # (the head's are zeros, an empty state, from the start)
            head = np.zeros((size, self._split))
            head[:first] = self._head[:first]
            slot = np.empty(size, np.int32)
            slot[:first] = self._slot[:first]
            track = np.empty((size, len(_TRACK_FIELDS)))
            track[:first] = self._track[:first]
            self._head, self._slot, self._track = head, slot, track
        self._track[first:need] = np.nan
        self._track[first:need, _MODE] = UNSET
        self._slot[first:need] = -1
        self.n = need
        return np.arange(first, need)

    def restart(self, tracks) -> None:
        """Tracks start again from their next fix, which may be before their last (a device's clock set
        back): the filter's state, last fix and estimate are cleared; the frame and the noise are kept."""
        idx = np.unique(self._check(tracks))
        self._put(idx, np.zeros((len(idx), self._split + self._runs.shape[1])))
        self._track[idx, _T:] = np.nan

    def _rows(self, idx: np.ndarray) -> np.ndarray:
        """The engine's state rows of tracks ``idx`` (a copy)."""
        rows = np.zeros((len(idx), self._split + self._runs.shape[1]))
        rows[:, :self._split] = self._head[idx]
        slot = self._slot[idx]
        run = slot >= 0
        if run.any():
            rows[run, self._split:] = self._runs[slot[run]]
        return rows

    def _put(self, idx: np.ndarray, rows: np.ndarray) -> None:
        """Tracks ``idx`` (distinct) <- the engine's state ``rows``; a track's coasting state and run buffer are
        kept while it has a manoeuvre candidate pending or is in a run of rejected fixes (the engine reads
        them only then, and no more of the buffer than the run)."""
        self._head[idx] = rows[:, :self._split]
        slot = self._slot[idx]
        run = (rows[:, ST_STREAK] > 0) | (rows[:, ST_PENDING] != 0)
        kept = run & (slot >= 0)
        self._runs[slot[kept]] = rows[kept, self._split:]
        start = run & (slot < 0)
        self._reslot(idx[(slot >= 0) & ~run], idx[start], rows[start, self._split:])

    def _check(self, tracks) -> np.ndarray:
        idx = np.asarray(tracks, dtype=np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n):
            raise ParameterError(f"tracks: expected indices in 0..{self.n - 1}")
        return idx

    # ---- advancing ---------------------------------------------------------------------------------
    def advance(self, tracks, t, lat, lon, accuracy, *, checked: bool = False) -> dict:
        """Advance tracks with new fixes: rows sorted by track, each track's in time order and after
        its last fix; ``accuracy`` (m, 1-sigma) NaN where the fix has none.  Returns the estimate at
        each fix (:data:`ESTIMATE_FIELDS`, arrays of the rows).  ``checked=True``: the caller has
        checked all that itself (known tracks; 1-D float arrays of one length; finite times, positions
        in range; rows in that order): a live server's batch of a few dozen fixes spent a third of
        this call in the checks."""
        acc = accuracy
        if not checked:
            tracks = self._check(tracks)
            t, lat, lon, acc = (np.ascontiguousarray(a, dtype=float) for a in (t, lat, lon, acc))
            self._check_fixes(tracks, t, lat, lon, acc)
        N = len(t)
        if N == 0:
            return {k: np.empty(0) for k in ESTIMATE_FIELDS}
        out = np.empty((len(ESTIMATE_FIELDS), N))
        X = np.empty((N, 2, self.order + 1))
        P = np.empty((N, self.order + 1, self.order + 1))
        flag = np.empty(N, dtype=np.int8)
        B = 1 + int(np.count_nonzero(tracks[1:] != tracks[:-1]))   # tracks in the batch
        runs = np.empty((B, self._runs.shape[1]))   # the run's part of the tracks that start a run
        moved = np.empty((2, B), np.int64)            # the tracks whose run ended, those that started one
        spec, options, pop = self.spec, self.options, self.population
        missed, ended, started = _step_kernel(self.order)(
            tracks, t, lat, lon, acc, self._track, self._head, self._runs, self._slot,
            pop["c_accuracy"], pop["c_sigma"], pop["q"], _unset(options.sigma_m), _unset(options.q), spec.prior,
            float(spec.gate), int(spec.max_rej), float(spec.max_gap_s), X, P, flag, out, runs, moved)
        self._reslot(moved[0, :ended], moved[1, :started], runs[:started])
        if missed:
            raise ParameterError("tracks: an estimate is so far from its track's first fix that the vertical "
                                 "through it misses the ellipsoid")
        est = dict(zip(ESTIMATE_FIELDS, out))
        est["flag"] = flag.astype(np.int64)
        return est

    def _reslot(self, ended: np.ndarray, started: np.ndarray, rows: np.ndarray) -> None:
        """The runs' pool after a step: tracks ``ended`` give their rows back, tracks ``started`` take one
        for their run's part ``rows``."""
        if len(ended):
            self._free.extend(self._slot[ended].tolist())
            self._slot[ended] = -1
        k = len(started)
        if k:
            if len(self._free) < k:
                old = len(self._runs)
                size = max(2 * old, old + k, 64)
                self._runs = np.concatenate([self._runs, np.zeros((size - old, self._runs.shape[1]))])
                self._free.extend(range(old, size))
            self._slot[started] = self._free[-k:]
            del self._free[-k:]
            self._runs[self._slot[started]] = rows

    def _check_fixes(self, tracks, t, lat, lon, acc) -> None:
        """The checks of :meth:`advance` (``tracks`` in range already)."""
        if not tracks.ndim == t.ndim == lat.ndim == lon.ndim == acc.ndim == 1 or \
                not len(tracks) == len(lat) == len(lon) == len(acc) == len(t):
            raise ShapeError("tracks, t, lat, lon, accuracy: expected 1-D columns of one length")
        if not len(t):
            return
        if not (np.isfinite(t).all() and (np.abs(lat) <= 90.0).all() and (np.abs(lon) <= 180.0).all()):
            raise ParameterError("t, lat, lon: expected finite times and positions within [-90, 90] and "
                                 "[-180, 180] degrees")
        step = np.diff(tracks)
        if (step < 0).any():
            raise ParameterError("tracks: expected the rows sorted by track")
        if (np.diff(t)[step == 0] < 0).any():
            raise ParameterError("t: expected each track's new fixes in time order")
        first = np.concatenate(([True], step != 0))
        if (t[first] < self._track[tracks[first], _T]).any():   # NaN: a track without a fix
            raise ParameterError("t: a track's first new fix is before its last fix; a late fix cannot enter "
                                 "the filter's past")

    def _slow_var(self, tracks) -> np.ndarray:
        """The variance of the fix error's slow part of ``tracks`` (:func:`_track_slow_variance` of each):
        what the total error (the fixes' accuracy, else 5 m) leaves after the white part, as ``mptrack
        track`` takes it."""
        return _slow_variances(self._track, np.asarray(tracks, np.int64), _unset(self.options.sigma_m))

    # ---- what a track knows now --------------------------------------------------------------------
    def last_fix(self, i: int) -> tuple[float, float, float]:
        """(t, lat, lon) of track i's last filtered fix (NaN for a track without one)."""
        row = self._track[self._check([i])[0]]
        return float(row[_T]), float(row[_RAW_LAT]), float(row[_RAW_LON])

    def last_fixes(self, tracks) -> np.ndarray:
        """(K, 3): t, lat, lon of each track's last filtered fix (NaN where none)."""
        return self._track[self._check(tracks)][:, [_T, _RAW_LAT, _RAW_LON]]

    def summaries(self) -> list[dict]:
        """Each track's last fix and estimate: time, raw_lat, raw_lon, the ESTIMATE_FIELDS and the
        1-sigma ellipse (ell_major_m, ell_minor_m, ell_azimuth_deg)."""
        tr = self._track[:self.n]
        major, minor, az = ellipse(tr[:, _EST + 2], tr[:, _EST + 3], tr[:, _EST + 4])
        cols = {"time": tr[:, _T], "raw_lat": tr[:, _RAW_LAT], "raw_lon": tr[:, _RAW_LON],
                **{k: tr[:, _EST + j] for j, k in enumerate(ESTIMATE_FIELDS)},
                "ell_major_m": major, "ell_minor_m": minor, "ell_azimuth_deg": az}
        names = list(cols)
        return [dict(zip(names, row)) for row in zip(*(c.tolist() for c in cols.values()))]

    def position(self, i: int, t: float) -> dict:
        """Track i's estimate predicted to time ``t`` (at or after its last fix): lat, lon, vel_e,
        vel_n, the east/north covariance and its 1-sigma ellipse, and the flag of its last fix.  The
        prediction is x(t) = F(t - t_k) x(k/k), P(t) = F P F' + Q(t - t_k) of the motion and the fix
        error's slow part -- for regular fixes and a filter in steady state, the N-step steady-state
        prediction of Assimakis et al. 2016."""
        i = int(self._check([i])[0])
        tr = self._track[i]
        dt = float(t) - tr[_T]
        if not dt >= 0.0:
            raise ParameterError(f"t: expected a time at or after the track's last fix ({tr[_T]!r}), got {t!r}")
        x, P = self._estimate(i)
        order, n = self.order, self.order + 1
        F, Qu = np.empty((n, n)), np.empty((n, n))
        slow = transition.py_func(order, n, dt, SLOW_TAU_S, F, Qu) * self._slow_var(np.array([i]))[0]
        x = x @ F.T
        P = F @ P @ F.T + tr[_Q] * Qu
        P[order, order] += slow
        lat, lon = enu_to_geodetic(x[0:1, 0], x[1:2, 0], tr[_LAT0:_LAT0 + 1], tr[_LON0:_LON0 + 1])
        var = np.array([P[0, 0]])
        major, minor, az = ellipse(var, np.zeros(1), var)
        return {"lat": float(lat[0]), "lon": float(lon[0]), "vel_e": float(x[0, 1]), "vel_n": float(x[1, 1]),
                "var_e": float(P[0, 0]), "cov_en": 0.0, "var_n": float(P[0, 0]), "ell_major_m": float(major[0]),
                "ell_minor_m": float(minor[0]), "ell_azimuth_deg": float(az[0]), "flag": int(tr[_EST + 8])}

    def _estimate(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(x (2, n), P (n, n)) of track i after its last fix: per axis the chain and the fix error's slow
        part (n = order + 1)."""
        n = self.order + 1
        x0, p0 = state_layout.py_func(n)[:2]
        row = self._head[i]
        return row[x0:x0 + 2 * n].reshape(2, n).copy(), row[p0:p0 + n * n].reshape(n, n).copy()

    def origin(self, i: int) -> tuple[float, float]:
        """(lat0, lon0) of track i's local frame (its first fix)."""
        row = self._track[self._check([i])[0]]
        return float(row[_LAT0]), float(row[_LON0])

    # ---- noise -------------------------------------------------------------------------------------
    def estimate_noise(self, histories: list[dict]) -> dict:
        """The fix noise and process noise of tracks from their recent fixes (``histories``: one dict of
        arrays t, lat, lon, accuracy_m per track, in time order) by the maximum likelihood of
        ``mptrack track`` (tracks with few fixes take the pooled value): a dict of arrays c, q, mode
        and w_fill for :meth:`set_noise` (NaN rows: fewer than two fixes, nothing estimated).  Reads no
        track state, so it may run beside :meth:`advance`."""
        K = len(histories)
        out = {"c": np.full(K, np.nan), "q": np.full(K, np.nan), "mode": np.full(K, np.nan),
               "w_fill": np.full(K, np.nan)}
        keep = [j for j, h in enumerate(histories) if len(h["t"]) >= 2]
        if not keep:
            return out
        cols = {k: np.concatenate([histories[j][k] for j in keep]) for k in ("t", "lat", "lon", "accuracy_m")}
        ids = np.repeat(np.array([str(j) for j in keep], dtype=object), [len(histories[j]["t"]) for j in keep])
        frame = pd.DataFrame({"track_id": ids, "time": cols["t"], **cols})
        frame["row"] = np.arange(1, len(frame) + 1)
        table = FixTable.from_frame(frame)
        w, has_acc = fix_weights(table, self.options.sigma_m)
        noise = _estimate(table, w, has_acc, self.spec)
        out["c"][keep], out["q"][keep] = noise.c, noise.q
        out["mode"][keep] = np.where(has_acc, ACCURACY, SIGMA)
        out["w_fill"][keep] = np.where(has_acc, table.per_track_median(w), 1.0)
        return out

    def set_noise(self, tracks, noise: dict) -> None:
        """Tracks' noise <- :meth:`estimate_noise`'s (rows with NaN are left alone); the population
        values follow the medians over every track.

        A track starts with the population's noise, which may take as white an error that the
        track's own estimate finds slow (a receiver that smooths its fixes).  The part g moved into
        the slow error was averaged down as if white, so the estimate carries it: its error gets an
        independent component d of variance g in the position and -d in the slow part (P += g u u'
        with u = +1 at the position, -1 at the slow part), which leaves the fixes' prediction p + b
        as certain as it was and makes the position as uncertain as the total error says, as a track
        estimated from its start is (without it the slow part would grow only over its time constant,
        an hour, while the position's variance shrank to the new white part's)."""
        tracks = self._check(tracks)
        ok = np.isfinite(noise["c"])
        idx = tracks[ok]
        tr = self._track
        before = self._slow_var(idx)
        if self.options.sigma_m is None:
            tr[idx, _C], tr[idx, _MODE], tr[idx, _W_FILL] = noise["c"][ok], noise["mode"][ok], noise["w_fill"][ok]
        if self.options.q is None:
            tr[idx, _Q] = noise["q"][ok]
        grow = np.maximum(self._slow_var(idx) - before, 0.0)
        n = self.order + 1
        _, p0, _, pc0 = state_layout.py_func(n)[:4]
        b = self.order                             # the slow part's index; the position's is 0
        slot = self._slot[idx]
        pooled = slot >= 0                         # the coasting covariance is kept only for these
        for rows, at, g, start in ((self._head, idx, grow, p0),
                                   (self._runs, slot[pooled], grow[pooled], pc0 - self._split)):
            rows[at, start] += g                   # the filter's and the coasting covariance (n x n, row-major)
            rows[at, start + b * n + b] += g
            rows[at, start + b] -= g
            rows[at, start + b * n] -= g
        cal = tr[:self.n]
        for key, mode in (("c_accuracy", ACCURACY), ("c_sigma", SIGMA)):
            sel = (cal[:, _MODE] == mode) & np.isfinite(cal[:, _C])
            if sel.any() and self.options.sigma_m is None:
                self.population[key] = float(np.median(cal[sel, _C]))
        if self.options.q is None and np.isfinite(cal[:, _Q]).any():
            self.population["q"] = float(np.nanmedian(cal[:, _Q]))

    def noise(self, i: int) -> dict:
        """Track i's noise: fix variance factor c, process-noise density q, and whether c scales the
        fixes' accuracy^2 (else c is sigma^2)."""
        row = self._track[self._check([i])[0]]
        return {"c": float(row[_C]), "q": float(row[_Q]), "accuracy": row[_MODE] == ACCURACY}

    # ---- saving and restoring ---------------------------------------------------------------------
    def save_states(self, tracks) -> tuple:
        """A copy of ``tracks``' rows (for :meth:`restore_states`)."""
        idx = self._check(tracks)
        slot = self._slot[idx]
        return idx, self._head[idx], slot >= 0, self._runs[slot[slot >= 0]], self._track[idx], dict(self.population)

    def restore_states(self, saved: tuple) -> None:
        idx, head, in_run, runs, track, population = saved
        rows = np.zeros((len(idx), self._split + self._runs.shape[1]))
        rows[:, :self._split] = head
        rows[in_run, self._split:] = runs
        self._put(idx, rows)
        self._track[idx] = track
        self.population = population

    def states_bytes(self, tracks) -> list[bytes]:
        """Each track's whole state (engine state, frame, noise, last fix and estimate) as bytes; the
        engine's coasting state and run buffer only while the track has a manoeuvre candidate pending or
        is in a run (its bytes are shorter otherwise)."""
        idx = self._check(tracks)
        if not len(idx):
            return []
        head = self._layouts[-1]
        out = np.hstack([np.broadcast_to(head, (len(idx), head.size)), self._track[idx].astype("<f8").view(np.uint8),
                         states_to_bytes(self._rows(idx), self.order)])
        blob, size = out.tobytes(), out.shape[1]
        short = self._stored_sizes[0]
        return [blob[j * size:(j + 1) * size] if run else blob[j * size:j * size + short]
                for j, run in enumerate((self._slot[idx] >= 0).tolist())]

    def load_states(self, tracks, blobs: list[bytes]) -> None:
        """Tracks <- their :meth:`states_bytes`, all at once (a restart with 10^6 devices reads them in
        one pass); a ParameterError says what does not match this mptrack's layout or model."""
        tracks = self._check(tracks)
        if len(tracks) != len(blobs):
            raise ParameterError("blobs: expected one state per track")
        if not len(tracks):
            return
        end = _BLOB.size + 8 * len(_TRACK_FIELDS)   # the track scalars end, the engine's state begins
        head = end + self._engine_head.size           # the engine's header ends, its float64 begin
        width = self._split + self._runs.shape[1]
        short, full = self._stored_sizes
        sizes = np.fromiter(map(len, blobs), np.int64, len(blobs))
        for size in np.unique(sizes).tolist():
            sel = np.flatnonzero(sizes == size)
            raw = np.frombuffer(b"".join([blobs[i] for i in sel.tolist()]), dtype=np.uint8).reshape(len(sel), size)
            which = (raw[:, None, :_BLOB.size] == self._layouts[None]).all(axis=2)   # (rows, layouts)
            known = which[:, 1] if size == short else which.any(axis=1) if size == full else np.zeros(len(sel), bool)
            if not (known.all() and (raw[:, end:head] == self._engine_head).all()):
                self._refuse(raw[int(np.argmin(known))] if not known.all() else raw[0], end, full)
            rows = np.zeros((len(sel), width))
            rows[:, :(size - head) // 8] = raw[:, head:].copy().view("<f8")
            self._track[tracks[sel]] = raw[:, _BLOB.size:end].copy().view("<f8")
            self._put(tracks[sel], rows)

    def _refuse(self, blob: np.ndarray, end: int, full: int) -> None:
        """The ParameterError that says what in this stored state does not match this mptrack's layout."""
        magic, version, fields = _BLOB.unpack_from(blob.tobytes())
        if magic != _MAGIC or version not in (1, _VERSION) or fields != len(_TRACK_FIELDS):
            raise ParameterError(f"blobs: not live track states of this mptrack (layout {version}, {fields} fields)")
        stored = blob[end:].tobytes()
        order = state_order(stored)
        if order is not None and order != self.order:
            was = next((m.name for m in MODELS.values() if m.order == order), f"order-{order}")
            raise ParameterError(f"model: the stored states are of the {was} model, not {self.model.name}: continue "
                                 f"these tracks with the {was} model, or start new tracks (a new database) for another")
        if version == _VERSION:   # the run's part may be left out: zeros
            stored += bytes(max(0, full - blob.size))
        state_from_bytes(stored)   # says what does not match the engine's layout
        raise ParameterError("blobs: states of different layouts (written by different versions of mptrack)")

    def warm_up(self) -> None:
        """Compile the kernels (a few seconds the first time, cached on disk), so the first fixes are fast."""
        probe = LiveTracks(self.options)
        probe.add(1)
        n = 6
        probe.advance(np.zeros(n, np.int64), 1.7e9 + np.arange(n), 50.0 + 1e-5 * np.arange(n), np.full(n, 8.0),
                      np.full(n, 5.0))
        probe.position(0, 1.7e9 + n)
        probe.estimate_noise([{"t": 1.7e9 + np.arange(40.0), "lat": 50.0 + 1e-5 * np.arange(40), "lon": np.full(40, 8.0),
                               "accuracy_m": np.full(40, 5.0)}])


def _unset(value) -> float:
    """An option's value for the kernel: NaN when it is not set."""
    return math.nan if value is None else float(value)


@nb.njit(inline="always")
def _track_slow_variance(row, sigma_m):
    """The variance of the fix error's slow part of a track (its scalars ``row``; ``sigma_m`` NaN when the
    option is not set): :func:`._fix_error.slow_variance` of the accuracy^2 it was started with where its
    fixes state one, else of 1 (or sigma_m^2) -- what ``mptrack track`` takes."""
    by_accuracy = row[_MODE] == ACCURACY
    other = 1.0 if sigma_m != sigma_m else sigma_m ** 2
    return slow_variance(row[_C], row[_W_FILL] if by_accuracy else other, by_accuracy)


@nb.njit(**SEQ)
def _slow_variances(tr, tracks, sigma_m):
    out = np.empty(len(tracks))
    for j in range(len(tracks)):
        out[j] = _track_slow_variance(tr[tracks[j]], sigma_m)
    return out


_KERNELS = {}


def _step_kernel(order: int):
    """The live filter's step (:meth:`LiveTracks.advance`) with the model's order a compile-time constant."""
    if order not in _KERNELS:
        _KERNELS[order] = _make_step(order)
    return _KERNELS[order]


def _make_step(order: int):
    n = order + 1
    split = state_layout.py_func(n)[2]

    @nb.njit(**SEQ)
    def step(tracks, t, lat, lon, acc, tr, head, runs, slot, c_accuracy, c_sigma, q_population, sigma_m, q_option,
             prior, gate, max_rej, max_gap, X, P, flag, out, started_rows, moved):
        """Every track's new fixes (rows grouped by track) through the engine's gated filter, in place: the
        track's scalars ``tr``, its state (``head``, and ``runs[slot]`` while it is in a run), each fix's
        estimate into ``out`` (ESTIMATE_FIELDS by row).  Returns (fixes whose estimate is off the
        ellipsoid, tracks whose run ended -> moved[0, :ended], tracks that started one -> moved[1, :started]
        with their run's part in started_rows[:started])."""
        N = t.shape[0]
        wk = work(n, STREAK_CAP, STREAK_CAP)
        stats = np.empty(6)
        rev_n = np.zeros(1, np.int64)
        rev_flag, rev_nis = np.zeros(0, np.int8), np.zeros(0)
        rev_X, rev_P = np.zeros((0, 2, n)), np.zeros((0, n, n))
        ze, zn, w = np.empty(N), np.empty(N), np.empty(N)
        st = np.empty(head.shape[1] + runs.shape[1])
        nis = out[7]
        missed = ended = started = 0
        a0 = 0
        while a0 < N:
            i = tracks[a0]
            b0 = a0 + 1
            while b0 < N and tracks[b0] == i:
                b0 += 1
            row = tr[i]
            if row[_MODE] == UNSET:   # a new track: its frame and noise from its first fix
                has = math.isfinite(acc[a0]) and acc[a0] > 0.0
                row[_LAT0], row[_LON0] = lat[a0], lon[a0]
                row[_MODE] = ACCURACY if has else SIGMA
                row[_W_FILL] = acc[a0] ** 2 if has else 1.0
                row[_C] = c_accuracy if has else c_sigma
                row[_Q] = q_population
            if sigma_m == sigma_m:
                row[_C] = 1.0
            if q_option == q_option:
                row[_Q] = q_option
            lat0, lon0 = row[_LAT0], row[_LON0]
            s0, c0, w0 = origin_terms(lat0)
            for k in range(a0, b0):
                ze[k], zn[k] = enu_row(lat[k], lon[k], lat0, lon0, 0.0, s0, c0, w0)
                good = math.isfinite(acc[k]) and acc[k] > 0.0
                if sigma_m == sigma_m:
                    w[k] = acc[k] * acc[k] if good else sigma_m ** 2
                elif row[_MODE] == SIGMA:
                    w[k] = 1.0
                else:
                    w[k] = acc[k] * acc[k] if good else row[_W_FILL]
            sb2 = _track_slow_variance(row, sigma_m)
            st[:split] = head[i]
            s = slot[i]
            if s >= 0:
                st[split:] = runs[s]
            else:
                st[split:] = 0.0
            advance_track(st, t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], row[_C], row[_Q], sb2, SLOW_TAU_S, order,
                          prior, gate, max_rej, max_gap, True, X[a0:b0], P[a0:b0], nis[a0:b0], flag[a0:b0], stats,
                          rev_n, rev_flag, rev_nis, rev_X, rev_P, wk)
            head[i] = st[:split]
            in_run = st[ST_STREAK] > 0.0 or st[ST_PENDING] != 0.0
            if s >= 0 and in_run:
                runs[s] = st[split:]
            elif s >= 0:
                moved[0, ended] = i
                ended += 1
            elif in_run:
                moved[1, started] = i
                started_rows[started] = st[split:]
                started += 1
            for k in range(a0, b0):
                out[0, k], out[1, k] = geodetic_row(X[k, 0, 0], X[k, 1, 0], lat0, lon0, s0, c0, w0)
                missed += out[0, k] != out[0, k]
                out[2, k] = P[k, 0, 0]
                out[3, k] = 0.0
                out[4, k] = P[k, 0, 0]
                out[5, k] = X[k, 0, 1]
                out[6, k] = X[k, 1, 1]
                out[8, k] = flag[k]
            last = b0 - 1
            row[_T], row[_RAW_LAT], row[_RAW_LON] = t[last], lat[last], lon[last]
            for j in range(out.shape[0]):
                row[_EST + j] = out[j, last]
            a0 = b0
        return missed, ended, started

    return step
