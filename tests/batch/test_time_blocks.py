"""The batch engine's time blocks: eight steps of each n = 2, m = 1 axis as vectors (rows of one or more axes)."""

import re

import numpy as np
import pytest

from mptrack import batch, linear
from mptrack.batch._filters import BLOCK, _gain_blocks, gain_blocks, time_blocks
from mptrack.errors import NonFiniteError
from mptrack.models import LinearGaussianModel, assimakis_model_b
from mptrack.riccati import steady_state


def test_time_blocks_are_the_recursion_over_eight_steps():
    """C from time_blocks applied to x(8i-1) and z(8i .. 8i+7) gives the sixteen numbers the recursion
    x(k) = M(k) x(k-1) + V(k) z(k) stores, in out's order, for time-varying M, V."""
    rng = np.random.default_rng(5)
    N = 3
    M = rng.standard_normal((N * BLOCK, 2, 2)) * 0.6
    V = rng.standard_normal((N * BLOCK, 2, 1))
    C = time_blocks(M, V)
    assert C.shape == (N, 16 * (BLOCK + 2))
    x = rng.standard_normal(2)
    z = rng.standard_normal(N * BLOCK)
    for i in range(N):
        rows = C[i].reshape(BLOCK + 2, 2 * BLOCK)
        got = z[i * BLOCK:(i + 1) * BLOCK] @ rows[:BLOCK] + x @ rows[BLOCK:]
        want = []
        for s in range(BLOCK):
            k = i * BLOCK + s
            x = M[k] @ x + V[k, :, 0] * z[k]
            want.extend(x)
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13)


def _batch(rng, T):
    """Tracks of every length from 0 to 25 and longer ones with NaN at a block's first and last step,
    a whole block of NaN, a NaN in the last incomplete block, and at step 0."""
    lengths = np.concatenate([np.arange(26), [T] * 6])
    B = len(lengths)
    z = 5.0 * rng.standard_normal((B, T, 1))
    gaps = {26: [8], 27: [15], 28: list(range(16, 24)), 29: [T - 2], 30: [0], 31: [3, 11, 12, 40]}
    for b, steps in gaps.items():
        z[b, steps] = np.nan
    return z, lengths, rng.standard_normal((B, 2))


@pytest.mark.parametrize("T", [50, 203])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("kind", ["steady-state", "kalman"])
def test_time_blocks_equal_the_reference_around_every_block_edge(kind, dtype, T):
    """Each track equals the reference filter (float64: 1e-12 of the scale; float32 storage: 1e-6
    relative) on lengths 0 .. 25 (no block, one, parts of a block) and on tracks with NaN at a block's
    edges, a whole block of NaN and a NaN in the last steps; the padding is NaN.  T = 50: the Kalman
    gains have not settled (every block has its own coefficients); T = 203: they settle."""
    rng = np.random.default_rng(T)
    model = assimakis_model_b()
    z, lengths, x0 = _batch(rng, T)
    P0 = np.diag([3.0, 0.5])
    if kind == "steady-state":
        ss = steady_state(model)
        got = batch.steady_state_filter(model, z.astype(dtype), x0, lengths=lengths, steady=ss).x
        ref = lambda b, L: linear.steady_state_filter(model, z[b, :L], x0[b], steady=ss).x
    else:
        gains = batch.gain_sequence(model, T, P0)
        settled = _gain_blocks(gains, 1)[1]
        assert settled <= 8 if T == 203 else settled == T // BLOCK - 1
        got = batch.kalman_filter(model, z.astype(dtype), x0, lengths=lengths, gains=gains).x
        ref = lambda b, L: linear.kalman_filter(model, z[b, :L], x0[b], P0).x
    assert got.dtype == dtype
    tol = 1e-12 if dtype == np.float64 else 1e-6
    for b, L in enumerate(lengths):
        assert np.isnan(got[b, L:]).all()
        if L:
            want = ref(b, L)
            assert np.abs(got[b, :L] - want).max() <= tol * max(1.0, np.abs(want).max()), b


def test_settled_kalman_blocks_are_all_equal_and_the_ones_before_differ():
    """gain_blocks gives the coefficients up to the first block whose steps all have the last gains
    (every later block is the same; the kernel keeps it in registers), and no further: a long sequence
    costs no more memory for them; one that has not settled by its end has a block for each eight
    steps.  A sequence keeps them (one computation per sequence and number of axis blocks)."""
    model = assimakis_model_b()
    gains = batch.gain_sequence(model, 4000, np.eye(2))
    C, settled = _gain_blocks(gains, 1)
    assert _gain_blocks(gains, 1)[0] is C
    assert 0 < settled < 20 and C.shape == (1, settled + 1, 16 * (BLOCK + 2))
    full = time_blocks(gains.A, gains.K)
    np.testing.assert_array_equal(full[:settled + 1], C[0])
    assert (full[settled:] == C[0, settled]).all()
    before = slice(BLOCK * (settled - 1), BLOCK * settled)      # a step of the block before has other gains
    assert (gains.K[before] != gains.K[-1]).any() or (gains.A[before] != gains.A[-1]).any()
    still = LinearGaussianModel(np.eye(2), [[1.0, 0.0]], np.zeros((2, 2)), [[1.0]])   # P keeps shrinking
    g = batch.gain_sequence(still, 64, np.eye(2))
    C, settled = gain_blocks(g.A[:, None], g.K[:, None])
    assert settled == C.shape[1] - 1 == 7
    g = batch.gain_sequence(model, 7, np.eye(2))                   # no whole block
    C, settled = gain_blocks(g.A[:, None], g.K[:, None])
    assert C.shape == (1, 0, 160) and settled == 0


@pytest.mark.parametrize("kind", ["steady-state", "kalman"])
def test_an_infinity_in_a_block_with_a_nan_is_refused_by_name(kind):
    """A block with a NaN runs the scalar steps; an infinity in the same block is still refused."""
    model = assimakis_model_b()
    run = batch.steady_state_filter if kind == "steady-state" else batch.kalman_filter
    z = np.random.default_rng(2).standard_normal((3, 40, 1))
    z[1, 9] = np.nan
    z[1, 12] = np.inf
    with pytest.raises(NonFiniteError, match="^" + re.escape("z: contains infinite value inf at index (1, 12, 0)")):
        run(model, z)


@pytest.mark.parametrize("axes", [2, 3, 8, 9])
def test_rows_of_many_axes(axes):
    """Rows of up to MAX_AXES = 8 axes run the block kernels (their states on the stack; two and three
    axes block by block with whole-vector stores), more the generic kernels: all equal the reference
    axis by axis, with a gap in one axis."""
    from mptrack.batch._kernels import MAX_AXES

    assert MAX_AXES == 8
    model = assimakis_model_b()
    rng = np.random.default_rng(axes)
    z = rng.standard_normal((3, 37, axes))
    z[1, 10:13, axes - 1] = np.nan
    ss = steady_state(model)
    got = batch.per_axis(batch.steady_state_filter, model, z, steady=ss).x
    kf = batch.per_axis(batch.kalman_filter, model, z, None, np.eye(2)).x
    for b in range(3):
        for a in range(axes):
            want = linear.steady_state_filter(model, z[b, :, a:a + 1], steady=ss).x
            np.testing.assert_allclose(got[b, :, 2 * a:2 * a + 2], want, rtol=1e-12, atol=1e-12)
            want = linear.kalman_filter(model, z[b, :, a:a + 1], None, np.eye(2)).x
            np.testing.assert_allclose(kf[b, :, 2 * a:2 * a + 2], want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("axes, T, gaps", [(1, 4500, [2047, 2048, 4100]), (2, 2100, [1023, 1024, 2050]),
                                           (3, 1400, [679, 680, 700, 1361]), (8, 700, [255, 256, 300, 512])])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_chunk_edges(axes, T, gaps, dtype):
    """Rows are taken in chunks of 2048 measurements (2048 steps of one axis, 1024 of two, 680 of three,
    256 of eight): NaN just before and at a chunk's first step, a float32 chunk widened after a gap,
    and chunks after the Kalman gains settle all equal the reference axis by axis."""
    model = assimakis_model_b()
    rng = np.random.default_rng(axes)
    z = rng.standard_normal((2, T, axes))
    z[1, gaps, axes - 1] = np.nan
    ss = steady_state(model)
    got = batch.per_axis(batch.steady_state_filter, model, z.astype(dtype), steady=ss).x
    kf = batch.per_axis(batch.kalman_filter, model, z.astype(dtype), None, np.eye(2)).x
    tol = 1e-12 if dtype == np.float64 else 1e-5
    for b in range(2):
        for a in range(axes):
            want = linear.steady_state_filter(model, z[b, :, a:a + 1], steady=ss).x
            np.testing.assert_allclose(got[b, :, 2 * a:2 * a + 2], want, rtol=tol, atol=tol)
            want = linear.kalman_filter(model, z[b, :, a:a + 1], None, np.eye(2)).x
            np.testing.assert_allclose(kf[b, :, 2 * a:2 * a + 2], want, rtol=tol, atol=tol)
