"""LiveTracks, the engine advanced fix by fix: the same estimates as ``mptrack track`` on the same fixes
and noise, whatever the batches; states that survive bytes; predictions by the exact discretisation."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from _data import REAL_TRACES

import mptrack
from mptrack.errors import ParameterError, ShapeError
from mptrack.io import geodetic_to_enu, read_table
from mptrack.tracking import ESTIMATE_FIELDS, FLAGS, LiveTracks, TrackOptions, get_model
from mptrack.tracking._fix_error import SLOW_TAU_S
from mptrack.tracking._fixes import fix_error_model


def _traces() -> pd.DataFrame:
    car = read_table(REAL_TRACES["car"])
    hike = read_table(REAL_TRACES["hike"])
    return pd.concat([car, hike], ignore_index=True)


def _feed(live: LiveTracks, df: pd.DataFrame, ids: dict, batches: np.ndarray, checked: bool = False) -> dict:
    """Advance ``live`` with the fixes of ``df`` in arrival order, cut into batches at ``batches``
    (row positions of the time-ordered interleaving of every track); returns the estimates by row.
    ``checked``: the caller's checks only (as the server's ingest calls it)."""
    order = np.argsort(df["t"].to_numpy(), kind="stable")
    out = {k: np.full(len(df), np.nan) for k in ESTIMATE_FIELDS}
    for rows in np.split(order, batches):
        dev = np.array([ids[i] for i in df["track_id"].to_numpy()[rows]], dtype=np.int64)
        srt = np.lexsort((df["t"].to_numpy()[rows], dev))
        rows, dev = rows[srt], dev[srt]
        est = live.advance(dev, df["t"].to_numpy()[rows], df["lat"].to_numpy()[rows], df["lon"].to_numpy()[rows],
                           np.full(len(rows), np.nan), checked=checked)
        for k in ESTIMATE_FIELDS:
            out[k][rows] = est[k]
    return out


@pytest.mark.parametrize("checked", [False, True])
@pytest.mark.parametrize("cuts", ["one", "every fix", "random"])
def test_batches_of_any_size_give_the_estimates_of_mptrack_track(cuts, checked):
    df = _traces()
    sigma, q = 4.0, 0.5
    want = mptrack.track(df, sigma_m=sigma, q=q)
    live = LiveTracks(TrackOptions(sigma_m=sigma, q=q))
    ids = {t: int(i) for i, t in enumerate(pd.unique(df["track_id"]))}
    live.add(len(ids))
    n = len(df)
    batches = {"one": np.array([], int), "every fix": np.arange(1, n),
               "random": np.sort(np.random.default_rng(3).choice(np.arange(1, n), 60, replace=False))}[cuts]
    got = _feed(live, df, ids, batches, checked)
    e, nn = geodetic_to_enu(got["lat"], got["lon"], want["lat"].to_numpy(), want["lon"].to_numpy())
    assert np.max(np.hypot(e, nn)) < 1e-6
    np.testing.assert_allclose(got["var_e"], want["var_east_m2"], rtol=1e-9)
    assert list(np.array(FLAGS)[got["flag"].astype(int)]) == list(want["flag"])


def test_a_state_survives_bytes_and_a_failed_batch_can_be_undone():
    df = read_table(REAL_TRACES["car"])
    t, lat, lon = df["t"].to_numpy(), df["lat"].to_numpy(), df["lon"].to_numpy()
    acc = np.full(len(df), 6.0)
    a, b = LiveTracks(), LiveTracks()
    a.add(2)
    b.add(2)
    a.advance(np.zeros(50, np.int64), t[:50], lat[:50], lon[:50], acc[:50])
    b.load_states([1], [a.states_bytes([0])[0]])
    saved = a.save_states([0])
    ra = a.advance(np.zeros(54, np.int64), t[50:], lat[50:], lon[50:], acc[50:])
    rb = b.advance(np.ones(54, np.int64), t[50:], lat[50:], lon[50:], acc[50:])
    for k in ESTIMATE_FIELDS:
        np.testing.assert_array_equal(ra[k], rb[k])
    a.restore_states(saved)
    again = a.advance(np.zeros(54, np.int64), t[50:], lat[50:], lon[50:], acc[50:])
    np.testing.assert_array_equal(again["lat"], ra["lat"])
    # a server started again with the other model: the refusal names the models (not a layout's sizes)
    ca = LiveTracks(TrackOptions(model="ca"))
    ca.add(1)
    with pytest.raises(ParameterError, match="^model: the stored states are of the cv model, not ca: "):
        ca.load_states([0], [a.states_bytes([0])[0]])
    ca.advance(np.zeros(50, np.int64), t[:50], lat[:50], lon[:50], acc[:50])
    with pytest.raises(ParameterError, match="^model: the stored states are of the ca model, not cv: "):
        b.load_states([0], ca.states_bytes([0]))


def test_an_undone_batch_leaves_every_state_as_it_was_runs_included():
    """A batch that starts runs of rejected fixes on some tracks and ends them on others, undone: every
    track's whole state (the run's part in the pool included) is what it was."""
    rng = np.random.default_rng(3)
    live = LiveTracks()
    tracks = live.add(40)
    t = 1.7e9

    def batch(jump):
        nonlocal t
        t += 5.0
        lat = 50.0 + 1e-5 * tracks + np.where(jump, 0.05, 0.0) + rng.normal(0, 3e-5, 40)
        return live.advance(tracks, np.full(40, t), lat, 8.0 + rng.normal(0, 3e-5, 40), np.full(40, 5.0))

    for _ in range(10):
        batch(np.zeros(40, bool))
    batch(tracks % 2 == 0)                     # even tracks: an outlier, a run begins
    in_run = [len(b) for b in live.states_bytes(tracks)]
    assert len(set(in_run)) == 2
    before, saved = live.states_bytes(tracks), live.save_states(tracks)
    batch(tracks % 3 == 0)                     # runs go on, end and begin
    assert [len(b) for b in live.states_bytes(tracks)] != in_run
    live.restore_states(saved)
    assert live.states_bytes(tracks) == before


def test_states_stored_whole_by_the_first_layout_still_load():
    """Layout 1 stored the run's part of every state (zeros without a run); layout 2 leaves it out then.
    A server upgraded in place reads both, mixed, and whole states of both layouts have one size."""
    df = read_table(REAL_TRACES["car"])
    t, lat, lon = df["t"].to_numpy()[:30], df["lat"].to_numpy()[:30], df["lon"].to_numpy()[:30]
    lat = np.concatenate([lat, lat + np.r_[np.zeros(29), 0.05]])          # track 1 ends with an outlier: a run
    live = LiveTracks()
    live.add(2)
    live.advance(np.repeat([0, 1], 30), np.tile(t, 2), lat, np.tile(lon, 2), np.full(60, 6.0))
    short, in_run = live.states_bytes([0, 1])
    whole = short[:4] + (1).to_bytes(2, "little") + short[6:] + bytes(8 * live._runs.shape[1])
    assert len(short) < 0.4 * len(whole) and len(in_run) == len(whole)
    again = LiveTracks()
    again.add(3)
    again.load_states([2, 0, 1], [whole, short, in_run])
    assert again.states_bytes([0, 1, 2]) == [short, in_run, short] and again.states_bytes([]) == []
    with pytest.raises(ParameterError, match="layout"):
        again.load_states([0], [short[:4] + (1).to_bytes(2, "little") + short[6:]])   # layout 1 is always whole
    with pytest.raises(ParameterError, match="layout"):
        again.load_states([0, 1], [in_run, whole[:4] + (7).to_bytes(2, "little") + whole[6:]])


def test_the_prediction_is_the_exact_discretisation_of_the_model():
    """position(t) = F x, F P F' + Q with F, Q of the model discretised by Van Loan's method (an
    independent route to the engine's closed form)."""
    df = read_table(REAL_TRACES["car"])
    live = LiveTracks(TrackOptions(sigma_m=3.0, q=0.8))
    live.add(1)
    live.advance(np.zeros(len(df), np.int64), df["t"].to_numpy(), df["lat"].to_numpy(), df["lon"].to_numpy(),
                 np.full(len(df), np.nan))
    t_last = live.last_fix(0)[0]
    x, P = live._estimate(0)                       # the filter's state after the last fix, one axis each
    # the motion and the fix error's slow part (5 m total, 3 m white: 4 m slow, time constant 1 h), one axis
    model = fix_error_model(get_model("cv"), 0.8, 25.0 - 9.0, SLOW_TAU_S)[0]
    disc = model.discretize(25.0)
    F, Q = disc.F[:3, :3], disc.Q[:3, :3]
    now, ahead = live.position(0, t_last), live.position(0, t_last + 25.0)
    np.testing.assert_allclose(ahead["var_e"], (F @ P @ F.T + Q)[0, 0], rtol=1e-12)
    lat0, lon0 = live.origin(0)                    # the track's frame: positions move on by 25 s x velocity
    e, n = geodetic_to_enu(np.array([now["lat"], ahead["lat"]]), np.array([now["lon"], ahead["lon"]]),
                           np.full(2, lat0), np.full(2, lon0))
    np.testing.assert_allclose([e[1] - e[0], n[1] - n[0]], [25.0 * x[0, 1], 25.0 * x[1, 1]], atol=1e-6)
    with pytest.raises(ParameterError, match="after the track's last fix"):
        live.position(0, t_last - 1.0)


def test_bad_calls_are_refused_by_name():
    live = LiveTracks()
    live.add(2)
    with pytest.raises(ParameterError, match="tracks"):
        live.advance(np.array([1, 0]), np.array([1.7e9, 1.7e9]), np.array([50.0, 50.0]), np.array([8.0, 8.0]),
                     np.full(2, np.nan))
    with pytest.raises(ParameterError, match="tracks"):
        live.advance(np.array([5]), np.array([1.7e9]), np.array([50.0]), np.array([8.0]), np.full(1, np.nan))
    live.advance(np.array([0]), np.array([1.7e9]), np.array([50.0]), np.array([8.0]), np.full(1, np.nan))
    with pytest.raises(ParameterError, match="before its last fix"):
        live.advance(np.array([0]), np.array([1.7e9 - 5]), np.array([50.0]), np.array([8.0]), np.full(1, np.nan))
    with pytest.raises(ParameterError, match="time order"):
        live.advance(np.array([1, 1]), np.array([1.7e9, 1.7e9 - 1]), np.array([50.0, 50.0]), np.array([8.0, 8.0]),
                     np.full(2, np.nan))
    for lat, t in ((91.0, 1.7e9), (np.nan, 1.7e9), (50.0, np.inf)):
        with pytest.raises(ParameterError, match="t, lat, lon"):
            live.advance(np.array([1]), np.array([t]), np.array([lat]), np.array([8.0]), np.full(1, np.nan))
    with pytest.raises(ShapeError, match="one length"):
        live.advance(np.array([1]), np.array([1.7e9]), np.array([50.0, 50.0]), np.array([8.0]), np.full(1, np.nan))
    assert np.isnan(live.last_fix(1)[0])           # nothing refused reached the track


def test_a_smoothing_receiver_keeps_metres_of_uncertainty_after_its_noise_is_estimated():
    """The bike ride's receiver smooths its fixes: a live track starts with the population's white
    noise, and when its own estimate moves the error into the slow part, the position's variance
    becomes the total error's, as ``mptrack track`` reports from the start (25 m^2: 5 m per axis where
    the fixes state no accuracy); without moving the averaged-down part it fell to 0.4 m^2."""
    df = read_table(REAL_TRACES["bike"]).iloc[:400]
    want = mptrack.track(df)
    live = LiveTracks(TrackOptions())
    live.add(1)
    t, lat, lon = df["t"].to_numpy(), df["lat"].to_numpy(), df["lon"].to_numpy()
    nan = np.full(len(df), np.nan)
    first = 40
    est = live.advance(np.zeros(first, np.int64), t[:first], lat[:first], lon[:first], nan[:first])
    assert est["var_e"][-1] > 1.0                     # the population's 5 m white noise, averaged down
    noise = live.estimate_noise([{"t": t[:first], "lat": lat[:first], "lon": lon[:first], "accuracy_m": nan[:first]}])
    assert noise["c"][0] < 0.01                        # the receiver's fixes show millimetres between them
    live.set_noise([0], noise)
    est = live.advance(np.zeros(len(df) - first, np.int64), t[first:], lat[first:], lon[first:], nan[first:])
    np.testing.assert_allclose(est["var_e"][-100:], want["var_east_m2"].to_numpy()[-100:], rtol=0.05)
    assert np.all(est["var_e"] >= 20.0)


def test_runs_of_rejected_fixes_carry_across_batches_and_bytes():
    """A track keeps its coasting state and run of rejected fixes only while it has a manoeuvre candidate
    pending or is in a run (the rest of the fleet holds a quarter of the memory): candidates and runs
    that span batches -- isolated outliers, outliers that look like manoeuvres, a jump that ends in a
    restart -- give what one call gives, also through states_bytes in the middle of a run, with the
    buffers freed and reused among tracks."""
    rng = np.random.default_rng(11)
    n, tracks = 120, 6
    t = 1.7e9 + np.arange(n, dtype=float)
    rows = []
    for k in range(tracks):
        north = 3.0 * np.arange(n) + rng.normal(0.0, 3.0, n)
        north[20 + k] += 400.0                        # an isolated outlier
        north[40 + k] += 25.0 + 5.0 * k               # one that looks like a manoeuvre until the next fix
        north[60 + 3 * k:] += 900.0                   # a jump that stays: a run, then a restart
        lat = 50.0 + north / 111_000.0
        rows.append((np.full(n, k), t, lat, np.full(n, 8.0 + 0.01 * k)))
    dev, tt, lat, lon = (np.concatenate(c) for c in zip(*rows))
    acc = np.full(len(dev), 3.0)
    whole = LiveTracks()
    whole.add(tracks)
    want = whole.advance(dev, tt, lat, lon, acc)
    assert {"outlier", "reset"} <= {FLAGS[f] for f in want["flag"]}
    piece = LiveTracks()
    piece.add(tracks)
    got = {k: np.empty(len(dev)) for k in ESTIMATE_FIELDS}
    for i in range(n):                                # fix by fix, every track at each time
        sel = np.flatnonzero(tt == t[i])
        est = piece.advance(dev[sel], tt[sel], lat[sel], lon[sel], acc[sel])
        for k in ESTIMATE_FIELDS:
            got[k][sel] = est[k]
        if i == 63:                                   # track 1 in a run, the others not: a state survives bytes
            blobs = piece.states_bytes(np.arange(tracks))
            assert len({len(b) for b in blobs}) == 2    # with the run's part while in a run, short otherwise
            moved = LiveTracks()
            moved.add(tracks)
            moved.load_states(np.arange(tracks), blobs)
            piece = moved
    # one call relabels a run's rejected fixes once the restart comes, and a candidate manoeuvre once the
    # next fix says it was an outlier; fix by fix they were answered as they came: every other estimate,
    # and every final state, is the same
    relabelled = (got["flag"] == FLAGS.index("manoeuvre")) & (want["flag"] == FLAGS.index("outlier"))
    assert relabelled.sum() >= tracks // 2
    kept = (got["flag"] != FLAGS.index("outlier")) & ~relabelled
    assert (~kept).sum() < 0.1 * len(dev)
    for k in ESTIMATE_FIELDS:
        np.testing.assert_array_equal(got[k][kept], want[k][kept])
    assert piece.states_bytes(np.arange(tracks)) == whole.states_bytes(np.arange(tracks))
    assert len(piece._free) == len(piece._runs) > 0   # every run ended: every buffer is free again
