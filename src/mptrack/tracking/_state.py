"""One track's filter state in the tracking engine: a row of float64, and that row as bytes.

One track's complete filter state -- the estimate, the pending manoeuvre
candidate, the run of rejected fixes, the counters -- is one row of float64
(:data:`STATE_FIELDS`, :func:`state_size`), so that
:func:`._engine.advance_tracks` continues many tracks from their saved states
with their new fixes in one call.  A live server keeps one row per device and
stores it as bytes (:func:`state_to_bytes`).  The filter that reads and writes
the row is :mod:`._track_filter`.
"""

from __future__ import annotations

import struct

import numba as nb
import numpy as np

from ..errors import DTypeError, ParameterError, ShapeError
from ._chain import INLINE

__all__ = ["STREAK_CAP", "STATE_VERSION", "STATE_FIELDS", "state_layout", "state_size", "empty_states", "state_order",
           "load_block", "save_block", "check_order", "state_to_bytes", "states_to_bytes", "state_from_bytes"]

#: The rejected fixes in a row that a track's state keeps (the restart test's run and the fixes
#: before it that a restart may relabel).
STREAK_CAP = 16

#: Version of the state layout (bump it when the layout changes; :func:`state_from_bytes` checks it).
STATE_VERSION = 2
#: The scalar fields at the start of a state row, in order.  Then, for a chain of order r and
#: n = r + 1 states per axis (the chain and the fix error's slow part): the estimate x (2, n) and its
#: covariance P (n, n) after the last fix; the coasting state (the prediction) at a pending manoeuvre
#: candidate, x (2, n) and P (n, n); the candidate's fix (east, north, unit variance w); and the last
#: STREAK_CAP rejected fixes of the current run, oldest first, as four blocks of STREAK_CAP: times, east,
#: north, w.
STATE_FIELDS = (
    "fixes",        # fixes taken so far (0: an empty state; the next fix initialises the track)
    "t_last",       # time of the last fix (s)
    "pending",      # 1 if the last fix is a manoeuvre candidate (the next fix decides)
    "cand_nis",     # the candidate's NIS against the nominal prediction (its NIS if it is an outlier)
    "cand_loglik",  # its log-likelihood as a manoeuvre
    "cand_nis_m",   # its NIS under the manoeuvre hypothesis (its NIS if it is a manoeuvre)
    "window",       # rejected fixes in the restart test's window (<= max_rej)
    "streak",       # rejected fixes in a row (the state keeps the last STREAK_CAP)
    "before_flag",  # the flag of the fix before that run (a restart's reset rows join a reset before them)
    "loglik", "updates", "outliers", "resets", "nis_sum", "manoeuvres",   # the track's counters so far
)
#: Their indices in the row, and the header's length.
(ST_FIXES, ST_T_LAST, ST_PENDING, ST_CAND_E, ST_CAND_LL, ST_CAND_EM, ST_WINDOW, ST_STREAK, ST_BEFORE, ST_LOGLIK,
 ST_UPDATES, ST_OUTLIERS, ST_RESETS, ST_NIS_SUM, ST_MANOEUVRES) = range(len(STATE_FIELDS))
ST_HEADER = len(STATE_FIELDS)


@nb.njit(**INLINE)
def state_layout(n):
    """Offsets of x, P, the coasting x and P, the candidate's fix, the streak, and the row's size, for n
    states per axis."""
    x0 = ST_HEADER
    p0 = x0 + 2 * n
    xc0 = p0 + n * n
    pc0 = xc0 + 2 * n
    cand0 = pc0 + n * n
    streak0 = cand0 + 3
    return x0, p0, xc0, pc0, cand0, streak0, streak0 + 4 * STREAK_CAP


def state_size(order: int) -> int:
    """The length of one track's state row for a chain of ``order`` states per axis (2 cv, 3 ca)."""
    return state_layout.py_func(order + 1)[-1]


def empty_states(B: int, order: int) -> np.ndarray:
    """(B, state_size(order)) empty states: each track's next fix initialises it (flag init)."""
    return np.zeros((B, state_size(order)))


@nb.njit(**INLINE)
def load_block(n, st, x0, p0, x, P):
    """x (2, n), P (n, n) <- the row's blocks at offsets x0, p0 (:func:`state_layout`)."""
    for a in range(2):
        for i in range(n):
            x[a, i] = st[x0 + a * n + i]
    for i in range(n):
        for j in range(n):
            P[i, j] = st[p0 + i * n + j]


@nb.njit(**INLINE)
def save_block(n, st, x0, p0, x, P):
    """The row's blocks at offsets x0, p0 <- x (2, n), P (n, n)."""
    for a in range(2):
        for i in range(n):
            st[x0 + a * n + i] = x[a, i]
    for i in range(n):
        for j in range(n):
            st[p0 + i * n + j] = P[i, j]


def check_order(order) -> int:
    """``order`` as an int, or a ParameterError: the engine runs integrator chains of order 2 or 3."""
    if order not in (2, 3):
        raise ParameterError(f"order: the engine runs integrator chains of order 2 or 3, got {order!r}")
    return int(order)


# ---- the row as bytes ----------------------------------------------------------------------------------

_MAGIC = b"MPTS"
_HEAD = struct.Struct("<4sHBBI")   # magic, layout version, order, streak cap, number of float64


def state_to_bytes(state, order: int) -> bytes:
    """One track's state row as bytes (a header with the layout version, then little-endian float64)."""
    order = check_order(order)
    row = np.asarray(state, dtype=np.float64)
    if row.shape != (state_size(order),):
        raise ShapeError(f"state: expected one state row of {state_size(order)} values for order {order}, "
                         f"got shape {row.shape}")
    return states_to_bytes(row[None, :], order).tobytes()


def states_to_bytes(states, order: int) -> np.ndarray:
    """Track state rows (K, size) as K rows of bytes (uint8 (K, bytes)), each what :func:`state_to_bytes`
    gives for its row."""
    order = check_order(order)
    rows = np.asarray(states, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != state_size(order):
        raise ShapeError(f"states: expected state rows of {state_size(order)} values for order {order}, "
                         f"got shape {rows.shape}")
    head = np.frombuffer(_HEAD.pack(_MAGIC, STATE_VERSION, order, STREAK_CAP, rows.shape[1]), dtype=np.uint8)
    return np.hstack([np.broadcast_to(head, (len(rows), head.size)), rows.astype("<f8").view(np.uint8)])


def state_order(data: bytes) -> int | None:
    """The model order a track state's header (:func:`state_to_bytes`) names, whatever follows it; None
    if ``data`` does not start with one."""
    if len(data) < _HEAD.size:
        return None
    magic, _, order, _, _ = _HEAD.unpack_from(data)
    return int(order) if magic == _MAGIC else None


def state_from_bytes(data: bytes) -> tuple[np.ndarray, int]:
    """(state row, order) from :func:`state_to_bytes`; a ParameterError names what does not match."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise DTypeError(f"data: expected bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) < _HEAD.size:
        raise ParameterError(f"data: {len(data)} bytes is too short for a track state")
    magic, version, order, cap, n = _HEAD.unpack_from(data)
    if magic != _MAGIC:
        raise ParameterError("data: not a track state (its first bytes are not the state's magic)")
    if version != STATE_VERSION or cap != STREAK_CAP:
        raise ParameterError(f"data: a track state of layout version {version} (streak {cap}); this mptrack reads "
                             f"version {STATE_VERSION} (streak {STREAK_CAP}): restart the track from its fixes")
    if order not in (2, 3) or n != state_size(order) or len(data) != _HEAD.size + 8 * n:
        raise ParameterError(f"data: a track state of order {order} with {n} values in {len(data)} bytes does not "
                             "match its layout")
    return np.frombuffer(data, dtype="<f8", offset=_HEAD.size).astype(np.float64), int(order)
