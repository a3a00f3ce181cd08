"""One track's filter state as a row of numbers: a track advanced piece by piece from its saved state (as a
live server does, one fix or a few at a time) ends exactly where one run over all its fixes ends.

The decisions a later fix revises (a manoeuvre candidate found to be an outlier, a restart relabelling the
rejected fixes before it) reach back into earlier pieces; :func:`advance_tracks` reports them, and with
them applied the rows, NIS, flags and counters are those of one run, bit for bit.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mptrack.errors import DTypeError, ParameterError, ShapeError
from mptrack.tracking import FLAGS, get_model
from mptrack.tracking._engine import Revisions, advance_tracks
from mptrack.tracking._state import (STATE_VERSION, STREAK_CAP, empty_states, state_from_bytes, state_size,
                                     state_to_bytes)

from test_tracking_engine import GATE, random_tracks, run_engine, slow_error


def _prior(order):
    return get_model({2: "cv", 3: "ca"}[order]).prior_variances


def run_pieces(order, offsets, t, ze, zn, w, c, q, cuts, through_bytes=False, sb2=None, tau=None, max_gap=np.inf):
    """The tracks advanced in rounds: in round i, track b takes its rows cuts[b][i]:cuts[b][i+1] (relative
    to the track); the outputs go to their rows of the whole table and the revisions reported for rows of
    earlier rounds are applied there.  Returns the outputs and the flags of the revised rows, as revised
    (one entry per revision of a row of an earlier round)."""
    B, N = len(offsets) - 1, len(t)
    n = order + 1
    sb2 = np.zeros(B) if sb2 is None else sb2
    tau = np.full(B, 3600.0) if tau is None else tau
    X, P = np.full((N, 2, n), np.nan), np.full((N, n, n), np.nan)
    nis, flag = np.full(N, -1.0), np.full(N, -1, np.int8)
    states = empty_states(B, order)
    stats = np.zeros((B, 6))
    revised = []
    rounds = max(len(cb) for cb in cuts) - 1
    for i in range(rounds):
        lo = [offsets[b] + (cuts[b][i] if i < len(cuts[b]) - 1 else cuts[b][-1]) for b in range(B)]
        hi = [offsets[b] + (cuts[b][i + 1] if i < len(cuts[b]) - 1 else cuts[b][-1]) for b in range(B)]
        rows = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi)]).astype(np.int64)
        off = np.r_[0, np.cumsum(np.subtract(hi, lo))].astype(np.int64)
        Xi, Pi = np.empty((len(rows), 2, n)), np.empty((len(rows), n, n))
        nisi, flagi = np.empty(len(rows)), np.empty(len(rows), np.int8)
        rev = Revisions.empty(B, order)
        if through_bytes:
            rebuilt = []
            for b in range(B):
                row, o = state_from_bytes(state_to_bytes(states[b], order))
                assert o == order
                rebuilt.append(row)
            states = np.array(rebuilt)
        advance_tracks(states, off, t[rows], ze[rows], zn[rows], w[rows], c, q, sb2, tau, order, _prior(order), GATE,
                       order + 1, max_gap, Xi, Pi, nisi, flagi, stats, rev)
        X[rows], P[rows], nis[rows], flag[rows] = Xi, Pi, nisi, flagi
        for b in range(B):
            for d in range(rev.n[b]):
                j = lo[b] - 1 - d
                assert j >= offsets[b], "a revision before the track's first fix"
                flag[j] = rev.flag[b, d]
                revised.append(FLAGS[rev.flag[b, d]])
                if not np.isnan(rev.nis[b, d]):
                    nis[j] = rev.nis[b, d]
                X[j], P[j] = rev.X[b, d], rev.P[b, d]
    return (X, P, nis, flag, stats), revised


def random_cuts(rng, offsets, max_pieces):
    cuts = []
    for b in range(len(offsets) - 1):
        L = int(offsets[b + 1] - offsets[b])
        k = int(rng.integers(0, max_pieces))
        inner = np.sort(rng.integers(0, L + 1, k))
        cuts.append([0, *inner.tolist(), L])
    return cuts


def assert_same(one, pieces):
    names = ("X", "P", "nis", "flag", "stats")
    for name, a, b in zip(names, one, pieces):
        np.testing.assert_array_equal(a, b, err_msg=name)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), order=st.sampled_from([2, 3]), max_pieces=st.sampled_from([2, 5, 40]),
       slow=st.booleans(), max_gap=st.sampled_from([np.inf, 200.0]))
def test_any_split_into_pieces_equals_one_run(seed, order, max_pieces, slow, max_gap):
    """With or without the fix error's slow part, with or without new segments at gaps."""
    rng = np.random.default_rng(seed)
    offsets, t, ze, zn, w, c, q = random_tracks(rng, 5, max_len=60)
    q = q if order == 2 else q / 100.0
    sb2, tau = slow_error(rng, 5, slow)
    one = run_engine(order, offsets, t, ze, zn, w, c, q, smooth=False, sb2=sb2, tau=tau, max_gap=max_gap)
    pieces, _ = run_pieces(order, offsets, t, ze, zn, w, c, q, random_cuts(rng, offsets, max_pieces),
                           through_bytes=bool(seed % 2), sb2=sb2, tau=tau, max_gap=max_gap)
    assert_same(one, pieces)


@pytest.mark.parametrize("order", [2, 3])
def test_fix_by_fix_equals_one_run_where_every_rule_fires(order):
    """Every fix its own call (a device reporting one fix at a time) on tracks with outliers, manoeuvres,
    restarts and revisions that reach back across calls."""
    rng = np.random.default_rng(40 + order)
    offsets, t, ze, zn, w, c, q = random_tracks(rng, 40)
    q = q if order == 2 else q / 100.0
    sb2, tau = slow_error(rng, 40, True)
    one = run_engine(order, offsets, t, ze, zn, w, c, q, smooth=False, sb2=sb2, tau=tau, max_gap=200.0)
    cuts = [list(range(int(offsets[b + 1] - offsets[b]) + 1)) for b in range(40)]
    pieces, revised = run_pieces(order, offsets, t, ze, zn, w, c, q, cuts, sb2=sb2, tau=tau, max_gap=200.0)
    assert_same(one, pieces)
    # both rules revised fixes of earlier calls: candidates found to be outliers, restarts' relabelled runs
    assert revised.count("outlier") >= 3 and revised.count("reset") >= 10
    seen = {FLAGS[f] for f in one[3]}
    assert {"init", "update", "outlier", "reset", "manoeuvre"} <= seen


@pytest.mark.parametrize("order", [2, 3])
def test_the_counters_are_those_of_the_final_flags(order):
    """updates, outliers and manoeuvres count the rows of each flag, resets the runs of reset rows, and the
    NIS sum adds the NIS of the updates and manoeuvres, after every revision."""
    rng = np.random.default_rng(7 + order)
    offsets, t, ze, zn, w, c, q = random_tracks(rng, 60)
    q = q if order == 2 else q / 100.0
    _, _, nis, flag, stats = run_engine(order, offsets, t, ze, zn, w, c, q, smooth=False)
    names = np.array(FLAGS)[flag]
    for b in range(len(offsets) - 1):
        f = names[offsets[b]:offsets[b + 1]]
        reset = f == "reset"
        used = (f == "update") | (f == "manoeuvre")
        assert stats[b, 1] == (f == "update").sum() and stats[b, 2] == (f == "outlier").sum()
        assert stats[b, 5] == (f == "manoeuvre").sum()
        assert stats[b, 3] == (reset & ~np.r_[False, reset[:-1]]).sum()
        assert stats[b, 4] == pytest.approx(nis[offsets[b]:offsets[b + 1]][used].sum(), rel=1e-12)


def test_back_to_back_restarts_are_one_run_of_resets():
    """A jump right after a restart's run: the second run of reset rows joins the first (one reset in the
    counters, as the flags show one run), also when the track arrives fix by fix."""
    t = np.arange(40.0)
    e = 3.0 * t
    e[20:] += 500.0
    e[23:] += 500.0
    args = (np.array([0, 40], np.int64), t, e, -t, np.full(40, 0.25), np.ones(1), np.full(1, 0.05))
    one = run_engine(2, *args, smooth=False)
    names = np.array(FLAGS)[one[3]]
    assert (names[20:26] == "reset").all() and names[26] == "update"
    assert one[4][0, 3] == 1
    pieces, _ = run_pieces(2, *args, [list(range(41))])
    assert_same(one, pieces)


def test_a_state_round_trips_through_bytes_and_refuses_what_is_not_one():
    states = empty_states(1, 2)
    t = np.arange(5.0)
    ze, zn = 3.0 * t, -t
    args = (np.array([0, 5], np.int64), t, ze, zn, np.ones(5), np.ones(1), np.ones(1), np.full(1, 4.0),
            np.full(1, 60.0), 2, _prior(2), GATE, 3, np.inf, np.empty((5, 2, 3)), np.empty((5, 3, 3)), np.empty(5),
            np.empty(5, np.int8), np.zeros((1, 6)))
    advance_tracks(states, *args)
    data = state_to_bytes(states[0], 2)
    assert len(data) == 12 + 8 * state_size(2)
    row, order = state_from_bytes(data)
    assert order == 2 and np.array_equal(row, states[0])
    with pytest.raises(ParameterError, match="magic"):
        state_from_bytes(b"XXXX" + data[4:])
    with pytest.raises(ParameterError, match=f"version {STATE_VERSION + 1}"):
        state_from_bytes(data[:4] + (STATE_VERSION + 1).to_bytes(2, "little") + data[6:])
    with pytest.raises(ParameterError, match="does not match"):
        state_from_bytes(data[:-8])
    with pytest.raises(ShapeError, match="state"):
        state_to_bytes(states[0], 3)


def test_advance_refuses_a_fix_before_the_last_and_bad_arrays():
    states = empty_states(1, 2)
    t = np.array([10.0, 11.0])
    out = lambda n: (np.empty((n, 2, 3)), np.empty((n, 3, 3)), np.empty(n), np.empty(n, np.int8),  # noqa: E731
                     np.zeros((1, 6)))
    common = (np.ones(1), np.ones(1), np.full(1, 4.0), np.full(1, 60.0), 2, _prior(2), GATE, 3, np.inf)
    advance_tracks(states, np.array([0, 2], np.int64), t, t, t, np.ones(2), *common, *out(2))
    with pytest.raises(ParameterError, match="before its last fix"):
        advance_tracks(states, np.array([0, 1], np.int64), np.array([5.0]), t[:1], t[:1], np.ones(1), *common,
                       *out(1))
    with pytest.raises(ParameterError, match="time order"):
        advance_tracks(empty_states(1, 2), np.array([0, 2], np.int64), t[::-1].copy(), t, t, np.ones(2), *common,
                       *out(2))
    with pytest.raises(DTypeError, match="offsets"):
        advance_tracks(states, [0, 2], t + 5, t, t, np.ones(2), *common, *out(2))
    with pytest.raises(ParameterError, match="max_rej"):
        advance_tracks(states, np.array([0, 2], np.int64), t + 5, t, t, np.ones(2), *common[:7], STREAK_CAP + 1,
                       np.inf, *out(2))
    with pytest.raises(ParameterError, match="sb2"):
        advance_tracks(states, np.array([0, 2], np.int64), t + 5, t, t, np.ones(2), np.ones(1), np.ones(1),
                       np.full(1, -1.0), *common[3:], *out(2))
