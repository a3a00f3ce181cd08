"""The columnar tracking engine: the gated filter of every track of a table of position fixes in one
compiled pass, from each track's first fix or continued from its saved state.

Layout (docs/design.md, "Tracking: columns and offsets"): the fixes of B
tracks are flat columns sorted by (track, time); track b is rows
``offsets[b]:offsets[b+1]``.  The kernel loops over tracks with ``prange`` and
over a track's fixes in order; no Python runs per track, and each block of
tracks allocates one workspace (:func:`._chain.work`), nothing per track or
per fix.

The engine is three modules: this one (the parallel kernel and its two entry
points, with their argument checks), :mod:`._track_filter` (the gated filter
of one track and its RTS pass, on the integrator-chain algebra of
:mod:`._chain`) and :mod:`._state` (one track's complete filter state as a row
of float64, and as bytes).  :func:`advance_tracks` continues many tracks from
their saved states with their new fixes in one call, and
:func:`filter_tracks` is the same kernel from empty states (optionally
followed by the RTS pass).  The likelihood that noise estimation maximises
runs the same chain algebra in :mod:`._likelihood`.

Rows decided again later.  Two rules revise the decision on an earlier fix:
the fix after a manoeuvre candidate decides whether it was a manoeuvre or an
outlier (one fix back), and a restart relabels the rejected fixes of its run,
and those just before it that lie inside the gate of the new stretch's state
predicted back to them, as the start of the new stretch (flag reset, the new
stretch's state; at most :data:`._state.STREAK_CAP` fixes back, the rejected
fixes the state keeps).  Rows of the same call are rewritten in place; rows
of an earlier call are reported in a :class:`Revisions` record (what each of
them is now), so that a track advanced piece by piece ends with the same
rows, NIS and counters as one run over all its fixes, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from .._core.threads import launch
from ..errors import DTypeError, ParameterError, ShapeError
from ._chain import BLOCKS, PAR, work
from ._state import ST_FIXES, ST_T_LAST, STREAK_CAP, check_order, empty_states, state_size
from ._track_filter import advance_track, smooth_track

__all__ = ["Revisions", "advance_tracks", "filter_tracks"]


@dataclass(frozen=True, eq=False)
class Revisions:
    """What :func:`advance_tracks` decided again about fixes of earlier calls (see the module doc).

    n     (B,) how many fixes before the call's first fix of track b were revised: entry i < n[b]
          is the fix i + 1 rows before it (the most recent first)
    flag  (B, R) their flags now; nis (B, R) their NIS now (NaN: unchanged)
    X, P  (B, R, 2, order + 1), (B, R, order + 1, order + 1) their states now (written where the call
          stores states)
    R = STREAK_CAP holds every revision a call can make.
    """

    n: np.ndarray
    flag: np.ndarray
    nis: np.ndarray
    X: np.ndarray
    P: np.ndarray

    @classmethod
    def empty(cls, B: int, order: int) -> Revisions:
        R, n = STREAK_CAP, order + 1
        return cls(np.zeros(B, np.int64), np.zeros((B, R), np.int8), np.full((B, R), np.nan),
                   np.zeros((B, R, 2, n)), np.zeros((B, R, n, n)))


# ---- the parallel kernel, compiled once per model order ------------------------------------------------

def _make_kernel(order: int):
    """The parallel kernel with ``order`` a compile-time constant (the small per-fix loops unroll;
    a runtime order made them 3x slower).  numba caches each closure per constant."""

    @nb.njit(**PAR)
    def advance_kernel(states, offsets, t, ze, zn, w, c, q, sb2, tau, prior, gate, max_rej, max_gap, store, smooth,
                       X, P, nis, flag, stats, rev_n, rev_flag, rev_nis, rev_X, rev_P):
        B = offsets.shape[0] - 1
        nblk = min(B, BLOCKS)
        for blk in nb.prange(nblk):
            wk = work(order + 1, STREAK_CAP, STREAK_CAP)
            for b in range(blk * B // nblk, (blk + 1) * B // nblk):
                a0 = offsets[b]
                b0 = offsets[b + 1]
                advance_track(states[b], t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], c[b], q[b], sb2[b], tau[b], order,
                              prior, gate, max_rej, max_gap, store, X[a0:b0], P[a0:b0], nis[a0:b0], flag[a0:b0],
                              stats[b], rev_n[b:b + 1], rev_flag[b], rev_nis[b], rev_X[b], rev_P[b], wk)
                if smooth and store and b0 > a0:
                    smooth_track(t[a0:b0], ze[a0:b0], zn[a0:b0], w[a0:b0], c[b], q[b], sb2[b], tau[b], order, gate,
                                 flag[a0:b0], X[a0:b0], P[a0:b0], wk)

    return advance_kernel


_KERNELS = {}


def _kernel(order: int):
    if order not in _KERNELS:
        if order not in (2, 3):
            raise ValueError(f"order: the engine runs integrator chains of order 2 or 3, got {order}")
        _KERNELS[order] = _make_kernel(order)
    return _KERNELS[order]


def _no_revisions(B: int, order: int) -> tuple:
    n = order + 1
    return (np.zeros(B, np.int64), np.zeros((B, 0), np.int8), np.zeros((B, 0)), np.zeros((B, 0, 2, n)),
            np.zeros((B, 0, n, n)))


def filter_tracks(offsets, t, ze, zn, w, c, q, sb2, tau, order, prior, gate, max_rej, max_gap, store, smooth, X, P,
                  nis, flag, stats):
    """Gated Kalman filter (and RTS smoother) of every track from its first fix; fills the outputs in place.

    offsets  (B+1,) track b is rows offsets[b]:offsets[b+1]; rows in time order
    t, ze, zn  (N,) seconds, east and north metres of the fixes
    w, c     the white part of the fix error of row k in track b has variance c[b] w[k] (m^2 per axis)
    q        (B,) process-noise density of each track (m^2/s^3 for order 2)
    sb2, tau (B,) the fix error's slow part: stationary variance (m^2 per axis; 0: none) and time constant (s)
    order    chain states per axis: 2 (cv) or 3 (ca); the state has n = order + 1 per axis
    prior    (order,) prior variances of the derivatives at a track's first fix (entry 0 unused)
    gate     NIS threshold (inf: no gating): a fix above it is tried against the manoeuvre
             hypothesis (density ``_track_filter.MANOEUVRE_FACTOR`` q) and else rejected; ``max_rej`` rejections in a
             row restart the track if they agree with each other (:func:`._track_filter._restart`)
    max_gap  a fix more than this many seconds after the last starts a new segment (inf: never)
    X, P     (N, 2, n), (N, n, n): the states, written if ``store`` (else left as they are)
    smooth   replace the stored filtered states by RTS-smoothed ones
    nis, flag (N,)  NIS of each fix (NaN at a track's first fix), index into ``FLAGS``
    stats    (B, 6)  loglik, updates, outliers, resets, NIS sum of the updates and manoeuvres, manoeuvres

    The same kernel as :func:`advance_tracks`, from empty states, in one call.
    """
    B = len(offsets) - 1
    _kernel(order)(empty_states(B, order), offsets, t, ze, zn, w, c, q, sb2, tau, prior, gate, max_rej, max_gap, store,
                   smooth, X, P, nis, flag, stats, *_no_revisions(B, order))


def advance_tracks(states, offsets, t, ze, zn, w, c, q, sb2, tau, order, prior, gate, max_rej, max_gap, X, P, nis,
                   flag, stats, revisions: Revisions | None = None, *, store: bool = True) -> None:
    """Continue the gated filter of B tracks from their states with their new fixes, in one call.

    Parameters
    ----------
    states : (B, state_size(order)) float64
        Each track's state (:func:`._state.empty_states` for a new track); updated in place.
    offsets : (B+1,) int64
        Track b's new fixes are rows offsets[b]:offsets[b+1] of the columns, in time order, none
        before the track's last fix (a track without new fixes is left as it is).
    t, ze, zn, w : (N,) float64
        Times (s), east and north (m) of the fixes, and their unit variances: the white part of fix
        k's error in track b has variance c[b] w[k] per axis.
    c, q, sb2, tau : (B,) float64
        Fix-variance factor, process-noise density, the fix error's slow part (stationary variance,
        m^2 per axis, and time constant, s) of each track for these fixes.
    order, prior, gate, max_rej, max_gap
        As in :func:`filter_tracks`.
    X, P, nis, flag : (N, 2, order + 1), (N, order + 1, order + 1), (N,), (N,) int8
        Written for the new rows: each fix's state (if ``store``), NIS and flag, as decided by the
        end of this call.
    stats : (B, 6) float64
        Written: each track's counters over all its fixes so far (:func:`filter_tracks`).
    revisions : Revisions or None
        Filled with the fixes of earlier calls whose decision this call revised (the module doc);
        None: not reported.

    Raises
    ------
    ShapeError, DTypeError, ParameterError
        An array of the wrong shape or dtype, offsets that do not delimit the rows, a fix before
        its track's last fix or out of time order, a non-finite fix, noise parameters out of range.

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    .. [2] A. Gelb (ed.), Applied Optimal Estimation, MIT Press, 1974.
    """
    order = check_order(order)
    n = order + 1
    states = _array("states", states, np.float64, 2)
    B = states.shape[0]
    if states.shape[1] != state_size(order):
        raise ShapeError(f"states: expected shape ({B}, {state_size(order)}) for order {order}, got {states.shape}")
    offsets = _array("offsets", offsets, np.int64, 1)
    t, ze, zn, w = (_array(k, v, np.float64, 1) for k, v in (("t", t), ("ze", ze), ("zn", zn), ("w", w)))
    N = t.shape[0]
    if offsets.shape != (B + 1,) or offsets[0] != 0 or offsets[-1] != N or np.any(np.diff(offsets) < 0):
        raise ParameterError(f"offsets: expected {B + 1} non-decreasing row offsets from 0 to {N}")
    for name, a in (("ze", ze), ("zn", zn), ("w", w)):
        if a.shape != (N,):
            raise ShapeError(f"{name}: expected shape ({N},), got {a.shape}")
    if not (np.isfinite(t).all() and np.isfinite(ze).all() and np.isfinite(zn).all() and (w > 0).all()
            and np.isfinite(w).all()):
        raise ParameterError("t, ze, zn, w: expected finite fixes with positive unit variances")
    counts = np.diff(offsets)
    starts = offsets[:-1][counts > 0]
    last = states[counts > 0, ST_T_LAST]
    fresh = states[counts > 0, ST_FIXES] == 0
    if np.any(np.diff(t) < 0) and np.any((np.diff(t) < 0) & ~np.isin(np.arange(1, N), starts)):
        raise ParameterError("t: expected each track's new fixes in time order")
    if np.any(~fresh & (t[starts] < last)):
        b = int(np.flatnonzero(counts > 0)[np.flatnonzero(~fresh & (t[starts] < last))[0]])
        raise ParameterError(f"t: track {b}'s first new fix (t = {t[offsets[b]]!r}) is before its last fix "
                             f"(t = {states[b, ST_T_LAST]!r}); a late fix cannot enter the filter's past")
    c, q, sb2, tau = (_array(k, v, np.float64, 1) for k, v in (("c", c), ("q", q), ("sb2", sb2), ("tau", tau)))
    for name, a in (("c", c), ("q", q), ("sb2", sb2), ("tau", tau)):
        if a.shape != (B,):
            raise ShapeError(f"{name}: expected shape ({B},), got {a.shape}")
    if not ((c > 0).all() and (q >= 0).all() and (sb2 >= 0).all() and (tau > 0).all()
            and np.isfinite(c).all() and np.isfinite(q).all() and np.isfinite(sb2).all()):
        raise ParameterError("c, q, sb2, tau: expected finite c > 0, q >= 0, sb2 >= 0 and tau > 0 (tau may be inf)")
    prior = _array("prior", prior, np.float64, 1)
    if prior.shape != (order,):
        raise ShapeError(f"prior: expected shape ({order},), got {prior.shape}")
    if not order + 1 <= int(max_rej) <= STREAK_CAP:
        raise ParameterError(f"max_rej: expected {order + 1} to {STREAK_CAP} rejections, got {max_rej!r}")
    if not float(max_gap) > 0:
        raise ParameterError(f"max_gap: expected a positive number of seconds (inf: never), got {max_gap!r}")
    for name, a, shape in (("X", X, (N, 2, n)), ("P", P, (N, n, n)), ("nis", nis, (N,)),
                           ("flag", flag, (N,)), ("stats", stats, (B, 6))):
        if a.shape != shape:
            raise ShapeError(f"{name}: expected shape {shape}, got {a.shape}")
    if flag.dtype != np.int8:
        raise DTypeError(f"flag: expected int8, got {flag.dtype}")
    rev = _no_revisions(B, order) if revisions is None else (revisions.n, revisions.flag, revisions.nis,
                                                             revisions.X, revisions.P)
    # small batches run on the calling thread, not waking the others (_core.threads)
    launch(_kernel(order), len(t), states, offsets, t, ze, zn, w, c, q, sb2, tau, prior, float(gate), int(max_rej),
           float(max_gap), bool(store), False, X, P, nis, flag, stats, *rev)


def _array(name: str, a, dtype, ndim: int) -> np.ndarray:
    if not isinstance(a, np.ndarray) or a.dtype != dtype or a.ndim != ndim or not a.flags.c_contiguous:
        got = type(a).__name__ + (f" {a.dtype} of shape {a.shape}" if isinstance(a, np.ndarray) else "")
        raise DTypeError(f"{name}: expected a C-contiguous {ndim}-D {np.dtype(dtype).name} array, got {got}")
    return a
