"""Batch engine ≡ the reference filters of mptrack.linear, track by track."""

import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mptrack import batch, linear
from mptrack.errors import DTypeError, NonFiniteError, ParameterError, ShapeError
from mptrack.models import LinearGaussianModel, assimakis_model_a, assimakis_model_b
from mptrack.result import BatchFilterResult
from mptrack.riccati import steady_state

TOL = 1e-12
SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def random_model(rng, n, m):
    F = rng.standard_normal((n, n))
    F *= rng.uniform(0.5, 1.1) / max(abs(np.linalg.eigvals(F)))
    H = rng.standard_normal((m, n))
    L = rng.standard_normal((n, n))
    Q = L @ L.T / n + 0.1 * np.eye(n)
    Lr = rng.standard_normal((m, m))
    R = Lr @ Lr.T / m + 0.5 * np.eye(m)
    return LinearGaussianModel(F, H, Q, R)


def close(a, b, tol=TOL):
    scale = max(1.0, float(np.nanmax(np.abs(b))))
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    assert float(np.nanmax(np.abs(a - b))) <= tol * scale


def with_gaps(rng, z, frac=0.1):
    z = z.copy()
    z[rng.random(z.shape) < frac] = np.nan
    return z


dims = st.tuples(st.integers(1, 4), st.integers(1, 3)).filter(lambda d: d[1] <= d[0] + 1)


@pytest.mark.parametrize("kind", ["steady-state", "kalman"])
@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), dims=dims, B=st.integers(1, 5), T=st.integers(1, 30),
       gaps=st.booleans())
def test_batch_filters_match_reference_on_random_models(kind, seed, dims, B, T, gaps):
    rng = np.random.default_rng(seed)
    model = random_model(rng, *dims)
    z = 3.0 * rng.standard_normal((B, T, model.m))
    if gaps:
        z = with_gaps(rng, z, 0.15)
    x0 = rng.standard_normal((B, model.n))
    if kind == "steady-state":
        ss = steady_state(model)
        res = batch.steady_state_filter(model, z, x0, steady=ss)
        want = [linear.steady_state_filter(model, z[b], x0[b], steady=ss) for b in range(B)]
    else:
        P0 = np.eye(model.n) * rng.uniform(0.0, 2.0)
        res = batch.kalman_filter(model, z, x0, P0)
        want = [linear.kalman_filter(model, z[b], x0[b], P0) for b in range(B)]
    for b in range(B):
        close(res.x[b], want[b].x)
        if kind == "steady-state":     # the shared steady covariance, as the reference reports it
            np.testing.assert_array_equal(res.run(b).P, want[b].P)


@pytest.mark.parametrize("model", [assimakis_model_b(), assimakis_model_a(2)], ids=["B", "A"])
def test_paper_models_complete_and_gappy(model):
    rng = np.random.default_rng(3)
    z = 10 * rng.standard_normal((7, 80, model.m))
    z[1, 5:9] = np.nan           # a gap
    z[2, 0] = np.nan             # missing first measurement
    z[3, 40:, :] = np.nan        # lost track
    if model.m > 1:
        z[4, 10, 0] = np.nan     # one component only
    P0 = np.eye(model.n)
    ss_b = batch.steady_state_filter(model, z, np.ones(model.n)).x
    kf_b = batch.kalman_filter(model, z, np.ones(model.n), P0).x
    for b in range(7):
        close(ss_b[b], linear.steady_state_filter(model, z[b], np.ones(model.n)).x)
        close(kf_b[b], linear.kalman_filter(model, z[b], np.ones(model.n), P0).x)


def test_complete_tracks_use_the_shared_gains_and_covariances():
    model = assimakis_model_b()
    gains = batch.gain_sequence(model, 50, np.eye(2))
    ref = linear.kalman_filter(model, np.zeros((50, 1)), P0=np.eye(2))
    np.testing.assert_allclose(gains.P_filt, ref.P, rtol=0, atol=1e-14)
    np.testing.assert_allclose(gains.P_pred, ref.P_pred, rtol=0, atol=1e-14)
    z = np.random.default_rng(0).standard_normal((3, 40, 1))
    np.testing.assert_array_equal(batch.kalman_filter(model, z, gains=gains).x,
                                  batch.kalman_filter(model, z, P0=np.eye(2)).x)


def test_ragged_lengths_equal_truncated_reference_and_nan_tail():
    model = assimakis_model_b()
    rng = np.random.default_rng(5)
    z = rng.standard_normal((4, 30, 1))
    lengths = np.array([30, 0, 17, 1])
    z_padded = z.copy()
    for b, L in enumerate(lengths):
        z_padded[b, L:] = np.nan     # padding is ignored whatever it holds
    for run, ref in ((batch.steady_state_filter, linear.steady_state_filter),
                     (batch.kalman_filter, lambda m, zb: linear.kalman_filter(m, zb, P0=np.zeros((2, 2)))),
                     (batch.fir_filter, linear.fir_filter)):
        got = run(model, z_padded, lengths=lengths).x
        for b, L in enumerate(lengths):
            assert np.isnan(got[b, L:]).all()
            if L:
                close(got[b, :L], ref(model, z[b, :L]).x)


def test_fir_filter_matches_reference_and_rejects_gaps():
    model = assimakis_model_a(2)
    z = np.random.default_rng(2).standard_normal((3, 40, 2))
    got = batch.fir_filter(model, z, M=12)
    for b in range(3):
        want = linear.fir_filter(model, z[b], M=12)
        close(got.x[b], want.x)
        np.testing.assert_array_equal(got.run(b).P, want.P)
    assert got.method == want.method == "FIR"
    default = batch.fir_filter(model, z)          # order from ||A^M|| < eps
    close(default.x[0], linear.fir_filter(model, z[0]).x)
    z[1, 7, 1] = np.nan
    with pytest.raises(NonFiniteError, match="track 1 has NaN at time index 7"):
        batch.fir_filter(model, z)


def test_per_axis_model_b_equals_reference_per_axis_and_model_a():
    axis = assimakis_model_b()
    rng = np.random.default_rng(4)
    z = rng.standard_normal((3, 60, 3))
    z[0, 10, 1] = np.nan
    x0 = rng.standard_normal(6)
    for run, ref, extra in ((batch.steady_state_filter, linear.steady_state_filter, ()),
                            (batch.kalman_filter, linear.kalman_filter, (np.eye(2),))):
        got = batch.per_axis(run, axis, z, x0, *extra)
        assert got.x.shape == (3, 60, 6)
        for b in range(3):
            want = linear.per_axis(ref, axis, z[b], x0, *(np.eye(6) for _ in extra))
            close(got.x[b], want.x)
            if run is batch.steady_state_filter:       # block-diagonal steady covariance
                np.testing.assert_array_equal(got.run(b).P, want.P)
    # model B per axis and model A jointly are the same filter on complete data (seed 000
    # eq. 17-18); with a gap in one axis the joint SS filter predicts every axis, per axis only one
    zc = np.nan_to_num(z)
    joint = batch.steady_state_filter(assimakis_model_a(3), zc, x0)
    close(batch.per_axis(batch.steady_state_filter, axis, zc, x0).x, joint.x, 1e-10)
    close(batch.per_axis(batch.fir_filter, axis, zc, M=9).x, batch.fir_filter(assimakis_model_a(3), zc, M=9).x)


def test_n_step_prediction_is_F_power_N_and_works_per_axis():
    model = assimakis_model_b()
    x = np.random.default_rng(6).standard_normal((2, 5, 4))
    got = batch.predict(model, x, 3)
    F3 = np.linalg.matrix_power(model.F, 3)
    np.testing.assert_allclose(got[..., :2], x[..., :2] @ F3.T, rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(got[..., 2:], x[..., 2:] @ F3.T, rtol=1e-15, atol=1e-15)
    y = x.copy()
    assert batch.predict(model, y, 3, out=y) is y  # in place
    np.testing.assert_array_equal(y, got)
    mixing = LinearGaussianModel([[0.9, 0.2], [0.3, 0.8]], [[1.0, 0.0]], np.eye(2), [[1.0]])
    x4 = x.copy()                                  # every component of F^N x uses every component of x
    want = (x.reshape(2, 5, 2, 2) @ np.linalg.matrix_power(mixing.F, 2).T).reshape(x.shape)
    np.testing.assert_allclose(batch.predict(mixing, x4, 2, out=x4), want, rtol=1e-14, atol=1e-15)


def test_float32_within_single_precision_and_out_in_place():
    model = assimakis_model_b()
    rng = np.random.default_rng(7)
    z = (5 * rng.standard_normal((6, 200, 1))).astype(np.float32)
    z[2, 50:60] = np.nan
    out = np.empty((6, 200, 2), dtype=np.float32)
    got = batch.steady_state_filter(model, z, out=out).x
    assert got is out and got.dtype == np.float32
    ref = batch.steady_state_filter(model, z.astype(np.float64)).x
    close(got.astype(np.float64), ref, 1e-6)
    kf = batch.kalman_filter(model, z, P0=np.eye(2)).x
    assert kf.dtype == np.float32
    close(kf.astype(np.float64), batch.kalman_filter(model, z.astype(np.float64), P0=np.eye(2)).x, 1e-6)


def test_float32_input_is_checked_in_its_dtype_without_a_float64_copy():
    """The infinity check of z runs in z's dtype: a float32 batch is not copied to float64 to be
    checked (that copy cost more CPU than the rest of the check; see docs/batch.md)."""
    import tracemalloc

    from mptrack.batch._inputs import as_batch

    z = np.ones((100, 1000, 1), np.float32)       # 400 kB; its float64 copy would be 800 kB
    z[1, 2, 0] = np.nan                            # NaN (missing) is allowed, infinity is not
    tracemalloc.start()
    try:
        assert as_batch("z", z, 1) is z
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200_000, peak                  # at most a boolean mask (1 byte per value) to find the NaN
    z[3, 4, 0] = -np.inf
    with pytest.raises(NonFiniteError, match=r"^z: contains infinite value .*inf.* at index \(3, 4, 0\)"):
        batch.steady_state_filter(assimakis_model_b(), z)


@pytest.mark.parametrize("kind", ["steady-state", "kalman"])
@pytest.mark.parametrize("which", ["B", "A", "coupled"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_an_infinity_anywhere_in_z_is_refused_by_name(kind, which, dtype):
    """The kernels check z while they read it (no pass over z before the filter): an infinity among a
    track's steps, beside a NaN in the same row (a row that only predicts, so the value is never used)
    or in the padding after the track's length gives the error naming z and the index, as before;
    ``out`` is then left unspecified, and a finite batch after it filters as usual."""
    from mptrack.bench.batch import _coupled

    # the block kernels (model B; model A's axes as rows of two) and the generic kernel (axes coupled)
    model = {"B": assimakis_model_b(), "A": assimakis_model_a(2), "coupled": _coupled(assimakis_model_a(2))}[which]
    run = batch.steady_state_filter if kind == "steady-state" else batch.kalman_filter
    rng = np.random.default_rng(31)
    z = rng.standard_normal((9, 40, model.m)).astype(dtype)
    lengths = np.array([40, 40, 40, 40, 40, 25, 40, 40, 40])
    want = run(model, z, lengths=lengths).x
    places = [(6, 17, 0), (5, 33, model.m - 1)]              # inside a track; after its length
    if model.m > 1:
        places.append((2, 8, 1))                             # beside a NaN: the row only predicts
        z[2, 8, 0] = np.nan
    for index in places:
        bad = z.copy()
        bad[index] = -np.inf
        pattern = r"^z: contains infinite value -inf at index " + re.escape(str(index))
        with pytest.raises(NonFiniteError, match=pattern):
            run(model, bad, lengths=lengths, out=np.empty(want.shape, dtype))
    np.testing.assert_array_equal(run(model, z[:, :, :], lengths=lengths).x[[0, 1, 3]], want[[0, 1, 3]])


@pytest.mark.parametrize("kind", ["steady-state", "kalman"])
@pytest.mark.parametrize("which", ["B", "A", "A3", "coupled"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_an_overflow_while_tracks_advance_together_is_an_error(kind, which, dtype):
    """An overflow inside the vector blocks (model B, model A's axes in 2-D and 3-D) and the generic
    kernel's four-track loop is found without a pass over the output: the call raises naming x0."""
    from mptrack.bench.batch import _coupled

    model = {"B": assimakis_model_b(), "A": assimakis_model_a(2), "A3": assimakis_model_a(3),
             "coupled": _coupled(assimakis_model_a(2))}[which]
    run = batch.steady_state_filter if kind == "steady-state" else batch.kalman_filter
    z = np.random.default_rng(3).standard_normal((8, 40, model.m)).astype(dtype)
    x0 = np.zeros((8, model.n))
    assert np.isfinite(run(model, z, x0).x).all()
    x0[5] = 1e39 if dtype == np.float32 else 1.75e308          # float32: overflows only when stored
    if dtype == np.float64:
        z[5, 0] = 1.7e308
    with pytest.raises(NonFiniteError, match=r"^x0: the (steady-state|Kalman) filter overflowed"):
        run(model, z, x0)


def test_the_float32_overflow_flag_misses_no_overflow():
    """The kernels find a float32 store that overflowed without reading it back: (OUT_SCALE * x) * 0.0 is
    NaN for every float64 state that float32 stores as +-inf (|x| >= (2 - 2**-24) 2**127) and, of the
    finite ones, only for |x| >= 2**127 (a flag makes the exact scan look; it is not the verdict)."""
    from mptrack.batch._kernels import OUT_SCALE

    edge = (2 - 2.0 ** -24) * 2.0 ** 127                     # the first value float32 rounds to inf
    xs = np.array([np.finfo(np.float32).max, np.nextafter(edge, 0), edge, np.nextafter(edge, np.inf), 1e39,
                   np.inf, np.nan, 1e300, 2.0 ** 127, np.nextafter(2.0 ** 127, 0), 1e38, 1.0, 0.0])
    xs = np.concatenate([xs, -xs])
    with np.errstate(over="ignore", invalid="ignore"):
        flagged = ~((OUT_SCALE[np.dtype(np.float32)] * xs) * 0.0 == 0.0)
        stored = ~np.isfinite(xs.astype(np.float32))
        assert stored.sum() == 12 and (flagged[stored]).all()
        assert (np.abs(xs[flagged & ~stored]) >= 2.0 ** 127).all() and (flagged & ~stored).sum() == 6
        assert (~((OUT_SCALE[np.dtype(np.float64)] * xs) * 0.0 == 0.0) == ~np.isfinite(xs)).all()


@pytest.mark.parametrize("kind", ["steady-state", "kalman"])
def test_a_float32_state_flagged_but_finite_is_not_an_error(kind):
    """States between 2**127 and float32's largest value are flagged by the kernel (see above) but stored
    finite: the exact scan then finds nothing and the call returns them."""
    model = LinearGaussianModel(0.5 * np.eye(2), [[1.0, 0.0]], 1e6 * np.eye(2), [[1.0]])   # gain ~ 1: x ~ z
    z = np.full((5, 8, 1), 3.0e38, np.float32)
    got = batch.steady_state_filter(model, z).x if kind == "steady-state" else batch.kalman_filter(
        model, z, x0=[3.0e38, 0.0]).x
    assert got.dtype == np.float32 and np.isfinite(got).all() and (np.abs(got[..., 0]) > 2.0 ** 127).all()


@pytest.mark.parametrize("kind", ["steady-state", "kalman"])
@pytest.mark.parametrize("axes", [2, 3])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_axes_of_one_model_run_as_lanes_and_equal_the_reference(kind, axes, dtype, monkeypatch):
    """A block-diagonal model of n = 2, m = 1 axes (model A; here also with a different R per axis) runs
    its axes as rows of the block kernels, with the joint model's rules: a steady-state row with a NaN
    in any axis only predicts, a Kalman track updates the axes it has.  Equal to the reference track by
    track, and to the generic kernel, on ragged tracks with whole-row, one-axis and first-step gaps; a
    model whose axes are coupled (Q across axes) takes the generic kernel and equals the reference too."""
    from mptrack.batch import _filters

    rng = np.random.default_rng(40 + axes)
    model = assimakis_model_a(axes)
    uneven = LinearGaussianModel(model.F, model.H, model.Q, np.diag(np.linspace(0.1, 0.3, axes)))
    v = np.zeros(model.n)
    v[[0, 2]] = 1.0                                   # a noise common to the x and y positions
    Qc = model.Q + 0.01 * np.outer(v, v)
    coupled = LinearGaussianModel(model.F, model.H, Qc, model.R)
    z = (10 * rng.standard_normal((9, 70, axes))).astype(dtype)
    z[1, 5:9] = np.nan
    z[2, 0, 0] = np.nan
    z[3, 20:30, axes - 1] = np.nan
    z[5, rng.random(70) < 0.3, 1] = np.nan
    lengths = np.array([70, 70, 70, 70, 33, 70, 70, 0, 70])
    x0 = rng.standard_normal((9, model.n))
    tol = 1e-5 if dtype == np.float32 else TOL
    for mdl, lanes in ((model, True), (uneven, True), (coupled, False)):
        ss, gains = steady_state(mdl), batch.gain_sequence(mdl, 70, np.eye(mdl.n))
        assert (_filters._lane_axes(mdl, 1, ss.A, ss.B, rtol=_filters._STEADY_RTOL) is not None) == lanes
        assert (_filters._lane_axes(mdl, 1, gains.K, gains.P_filt, gains.P0) is not None) == lanes
        if kind == "steady-state":
            def run():
                return batch.steady_state_filter(mdl, z, x0, lengths=lengths).x
            want = {b: linear.steady_state_filter(mdl, z[b, :lengths[b]].astype(np.float64), x0[b]).x
                    for b in range(9) if lengths[b]}
        else:
            def run():
                return batch.kalman_filter(mdl, z, x0, np.eye(mdl.n), lengths=lengths).x
            want = {b: linear.kalman_filter(mdl, z[b, :lengths[b]].astype(np.float64), x0[b], np.eye(mdl.n)).x
                    for b in range(9) if lengths[b]}
        got = run()
        for b in range(9):
            if b in want:
                close(got[b, :lengths[b]].astype(np.float64), want[b], tol)
            assert np.isnan(got[b, lengths[b]:]).all()
        if lanes:
            with monkeypatch.context() as patch:
                patch.setattr(_filters, "_lane_axes", lambda *a, **kw: None)     # the generic kernels
                generic = run()
            np.testing.assert_allclose(got, generic, rtol=1e-6 if dtype == np.float32 else 1e-12, atol=1e-12)


def test_bad_shapes_and_dtypes_raise_named_errors():
    model = assimakis_model_b()
    z = np.zeros((2, 5, 1))
    with pytest.raises(ShapeError, match=r"z: expected shape \(B, T, 1\), got shape \(5, 1\)"):
        batch.steady_state_filter(model, np.zeros((5, 1)))
    with pytest.raises(ShapeError, match="z: expected shape"):
        batch.kalman_filter(model, np.zeros((2, 5, 2)))
    with pytest.raises(ShapeError, match="at least one track"):
        batch.steady_state_filter(model, np.zeros((0, 5, 1)))
    with pytest.raises(DTypeError, match="z: expected real numbers"):
        batch.steady_state_filter(model, z.astype(complex))
    with pytest.raises(DTypeError, match="out: expected dtype float64"):
        batch.steady_state_filter(model, z, out=np.empty((2, 5, 2), np.float32))
    with pytest.raises(ShapeError, match=r"out: expected shape \(2, 5, 2\)"):
        batch.steady_state_filter(model, z, out=np.empty((2, 5, 3)))
    with pytest.raises(ShapeError, match="C-contiguous"):
        batch.steady_state_filter(model, z, out=np.empty((2, 2, 5)).transpose(0, 2, 1))
    with pytest.raises(ShapeError, match=r"x0: expected shape \(2, 2\)"):
        batch.steady_state_filter(model, z, np.zeros((3, 2)))
    with pytest.raises(ShapeError, match=r"lengths: expected shape \(2,\)"):
        batch.steady_state_filter(model, z, lengths=[5])
    with pytest.raises(ParameterError, match=r"lengths: expected values in \[0, 5\]"):
        batch.steady_state_filter(model, z, lengths=[5, 6])
    with pytest.raises(DTypeError, match="lengths: expected integers"):
        batch.steady_state_filter(model, z, lengths=[5.0, 5.0])
    with pytest.raises(ParameterError, match="model: expected a LinearGaussianModel"):
        batch.steady_state_filter("model B", z)
    with pytest.raises(ParameterError, match="run: expected"):
        batch.per_axis(linear.steady_state_filter, model, z)
    with pytest.raises(ShapeError, match=r"x: expected shape \(B, T, axes \* 2\)"):
        batch.predict(model, np.zeros((2, 5, 3)))
    with pytest.raises(ParameterError, match="steps: expected an integer >= 1"):
        batch.predict(model, np.zeros((2, 5, 2)), 0)
    with pytest.raises(ShapeError, match="gains: expected at least 5 gains"):
        batch.kalman_filter(model, z, gains=batch.gain_sequence(model, 3))
    with pytest.raises(ParameterError, match="P0: give P0 or gains"):
        batch.kalman_filter(model, z, P0=np.eye(2), gains=batch.gain_sequence(model, 5))


def test_integer_input_is_converted_to_float64():
    model = assimakis_model_b()
    z = np.arange(10).reshape(1, 10, 1)
    got = batch.steady_state_filter(model, z).x
    assert got.dtype == np.float64
    close(got[0], linear.steady_state_filter(model, z[0]).x)


@pytest.mark.parametrize("axes", [1, 3])
def test_interleaved_groups_with_mixed_lengths_and_gaps(axes):
    """The n=2, m=1 kernels advance four tracks together; lanes leave the group at gaps and ends."""
    model = assimakis_model_b()
    rng = np.random.default_rng(10 + axes)
    B, T = 11, 45
    z = 4 * rng.standard_normal((B, T, axes))
    z[rng.random(z.shape) < 0.03] = np.nan
    lengths = rng.integers(0, T + 1, B)
    lengths[:3] = T
    x0 = rng.standard_normal((B, 2 * axes))
    P0 = 0.5 * np.eye(2)
    for run, ref, extra in ((batch.steady_state_filter, linear.steady_state_filter, ()),
                            (batch.kalman_filter, linear.kalman_filter, (P0,))):
        got = batch.per_axis(run, model, z, x0, *extra, lengths=lengths).x
        for b in range(B):
            L = lengths[b]
            assert np.isnan(got[b, L:]).all()
            for a in range(axes):
                if L:
                    want = ref(model, z[b, :L, a:a + 1], x0[b, 2 * a:2 * a + 2], *extra).x
                    close(got[b, :L, 2 * a:2 * a + 2], want)


def test_parallel_launch_equals_single_thread_bitwise(monkeypatch):
    """Large batches run on all threads, small ones on one: the numbers must not depend on it."""
    from mptrack._core import threads as _threads

    model = assimakis_model_b()
    z = np.random.default_rng(9).standard_normal((401, 200, 1))
    z[7, 50:60] = np.nan
    monkeypatch.setattr(_threads, "SMALL_WORK", 0)
    parallel = [batch.steady_state_filter(model, z), batch.kalman_filter(model, z, P0=np.eye(2))]
    monkeypatch.setattr(_threads, "SMALL_WORK", 10**12)
    single = [batch.steady_state_filter(model, z), batch.kalman_filter(model, z, P0=np.eye(2))]
    for p, s in zip(parallel, single):
        np.testing.assert_array_equal(p.x, s.x)
    close(parallel[1].x[7], linear.kalman_filter(model, z[7], P0=np.eye(2)).x)


def test_results_hold_the_out_array_and_views_of_the_shared_covariances():
    """Every batch filter returns a BatchFilterResult made without copying: x is the ``out`` array
    itself, P (steady-state, FIR) a read-only stride-0 view of the one steady covariance, the
    shared steady state or gain sequence in ``inputs``; the fields the kernels do not form are None."""
    model = assimakis_model_b()
    z = np.random.default_rng(11).standard_normal((3, 20, 1))
    ss = steady_state(model)
    gains = batch.gain_sequence(model, 20, np.eye(2))
    runs = {"SSKF": lambda out: batch.steady_state_filter(model, z, out=out, steady=ss),
            "KF": lambda out: batch.kalman_filter(model, z, out=out, gains=gains),
            "FIR": lambda out: batch.fir_filter(model, z, out=out, steady=ss)}
    for method, run in runs.items():
        out = np.empty((3, 20, 2))
        res = run(out)
        assert isinstance(res, BatchFilterResult) and res.method == method and res.B == 3
        assert res.x is out
        for field in ("x_pred", "P_pred", "innovation", "S", "nis", "loglik", "x0", "P0"):
            assert getattr(res, field) is None, field
        if method == "KF":
            assert res.P is None and res.inputs["gains"] is gains
        else:
            assert res.inputs["steady"] is ss
            assert res.P.shape == (3, 20, 2, 2) and not res.P.flags.writeable
            assert res.P.strides[:2] == (0, 0) and np.shares_memory(res.P, ss.P_filt)
            np.testing.assert_array_equal(res.P[2, 19], ss.P_filt)
            with pytest.raises(ValueError):
                res.P[0, 0, 0, 0] = 1.0
    # per axis: the covariance is block-diagonal over the axes, still one (n, n) block of memory
    res = batch.per_axis(batch.steady_state_filter, model, np.repeat(z, 2, axis=2), steady=ss)
    assert res.P.shape == (3, 20, 4, 4) and res.P.strides[:2] == (0, 0)
    np.testing.assert_array_equal(res.P[0, 0], np.kron(np.eye(2), ss.P_filt))


def test_kalman_covariances_of_complete_tracks_are_the_shared_gain_sequence():
    """P is None (a track with a gap has its own covariances); a complete track's are the gain
    sequence's, which the result carries."""
    model = assimakis_model_b()
    z = np.random.default_rng(12).standard_normal((2, 25, 1))
    res = batch.kalman_filter(model, z, P0=np.eye(2))
    ref = linear.kalman_filter(model, z[0], P0=np.eye(2))
    np.testing.assert_allclose(res.inputs["gains"].P_filt, ref.P, rtol=0, atol=1e-14)
    np.testing.assert_allclose(res.inputs["gains"].P_pred, ref.P_pred, rtol=0, atol=1e-14)


def test_the_gain_sequence_gives_the_filter_matrices_of_complete_steps():
    """GainSequence.A(k) = [I - K(k) H] F, so x(k/k) = A(k) x + K(k) z(k) is the Kalman update of a
    complete step (the form the block kernels run); computed once per sequence."""
    model = assimakis_model_a(2)
    gains = batch.gain_sequence(model, 30, np.eye(4))
    A = gains.A
    assert A is gains.A and A.shape == (30, 4, 4)
    x, z = np.array([1.0, -2.0, 0.5, 3.0]), np.array([0.7, -1.1])
    for k in (0, 1, 29):
        xp = model.F @ x
        want = xp + gains.K[k] @ (z - model.H @ xp)
        np.testing.assert_allclose(A[k] @ x + gains.K[k] @ z, want, rtol=1e-14, atol=1e-14)


def test_predict_and_filter_chunked_name_a_result_where_an_array_is_expected():
    model = assimakis_model_b()
    z = np.zeros((2, 5, 1))
    res = batch.steady_state_filter(model, z)
    with pytest.raises(ParameterError, match=r"^x: expected the \(B, T, n\) states, got a BatchFilterResult"):
        batch.predict(model, res)
    np.testing.assert_array_equal(batch.predict(model, res.x), res.x)
    with pytest.raises(DTypeError, match=r"^run: expected a batch filter returning a BatchFilterResult"):
        batch.filter_chunked(lambda m, zz: batch.steady_state_filter(m, zz).x, model, z, chunk_size=1)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("kind", ["steady-state", "kalman"])
def test_an_overflow_inside_a_ragged_track_is_an_error_even_when_it_decays(kind, dtype):
    """The output check scans each track up to its length in the output's dtype: a float32
    store that overflowed for 4 steps, with finite rows after it, is found; the NaN rows after
    a track's end are not errors."""
    model = assimakis_model_b()
    z = np.random.default_rng(1).standard_normal((3, 300, 1)).astype(dtype)
    lengths = np.array([300, 250, 10])
    run = batch.steady_state_filter if kind == "steady-state" else batch.kalman_filter
    x0 = np.zeros((3, 2))
    fine = run(model, z, x0, lengths=lengths).x
    assert np.isnan(fine[2, 10:]).all() and np.isfinite(fine[2, :10]).all()
    x0[1] = 1e39 if dtype == np.float32 else 1.75e308   # float64: A x0 + B z overflows with z = 1.7e308
    if dtype == np.float64:
        z[1, 0] = 1.7e308
    out = np.empty((3, 300, 2), dtype)
    with pytest.raises(NonFiniteError, match=r"^x0: the (steady-state|Kalman) filter overflowed"):
        run(model, z, x0, out=out, lengths=lengths)
    if dtype == np.float32:
        assert not np.isfinite(out[1, 0]).all() and np.isfinite(out[1, 249]).all()
