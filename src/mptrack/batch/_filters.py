"""Batched linear filters: many tracks sharing one model, in compiled kernels.

Each function here is the batch twin of the reference filter of the same name
in :mod:`mptrack.linear` and is tested against it track by track.  They return a
:class:`mptrack.result.BatchFilterResult` whose x is the kernel's output array
(``out`` when given) and whose other fields cost nothing to make: the shared
covariance of the steady-state and FIR filters as a read-only broadcast view,
the shared steady state or gain sequence in ``inputs``, None for what the
kernels do not form (docs/decisions/2026-11-23-batch-engine.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Callable

import numpy as np

from .._core.finiteness import require_finite
from .._core.fir import check_order_rule, coefficients_unchecked
from .._core.steady_input import steady_argument
from .._core.validation import check_allocation, check_covariance, check_int, _to_array
from ..errors import NonFiniteError, ParameterError, ShapeError
from ..linear import fir_order
from ..models import LinearGaussianModel, require_model
from ..result import BatchFilterResult
from ..riccati import SteadyState
from . import _kernels as K
from ._inputs import as_batch, check_finite_out, check_flagged, check_out, launch, prepare_batch

__all__ = [
    "GainSequence",
    "gain_sequence",
    "steady_state_filter",
    "kalman_filter",
    "fir_filter",
    "predict",
    "per_axis",
]


def _axis_blocks(M: np.ndarray, k: int, rtol: float = 0.0) -> np.ndarray | None:
    """The k diagonal blocks (..., k, r, c) of ``M`` (..., k r, k c) when the blocks off the diagonal
    are zero (to ``rtol`` times M's largest entry), else None."""
    M = np.asarray(M, dtype=np.float64)
    r, c = M.shape[-2] // k, M.shape[-1] // k
    atol = rtol * float(np.abs(M).max(initial=0.0))
    blocks = np.empty(M.shape[:-2] + (k, r, c))
    for i in range(k):
        for j in range(k):
            part = M[..., i * r:(i + 1) * r, j * c:(j + 1) * c]
            if i == j:
                blocks[..., i, :, :] = part
            elif np.abs(part).max(initial=0.0) > atol:
                return None
    return blocks


#: How far from block diagonal with equal blocks the steady state of such a model may be: its solver works
#: on the joint matrices, so the zero blocks and the differences of equal ones come out as rounding
#: (2e-16 of the largest entry for model A).
_STEADY_RTOL = 1e-12


def _lane_axes(model: LinearGaussianModel, axes: int, *matrices, rtol: float = 0.0) -> tuple[int, list] | None:
    """How the n = 2, m = 1 block kernels run this model: (axes per row k, the blocks (..., q, r, c) of
    F, H, Q, R and ``matrices``), or None (the generic kernels).  q = 1 when every axis has the same
    blocks, else k.

    Model B-like axis models (n = 2, m = 1) run ``axes`` tracks per row (:func:`per_axis`); a model of k
    such axes -- F, H, Q, R block diagonal with 2 x 2, 1 x 2, 2 x 2, 1 x 1 blocks, exactly, as
    :func:`mptrack.models.stack_axes` builds them (the axes may differ, e.g. in R) -- runs each axis as a
    track when ``matrices`` (its steady state or gains) are block diagonal too (to ``rtol``)."""
    mats = (model.F, model.H, model.Q, model.R, *matrices)
    if model.n == 2 and model.m == 1:     # one block for all axes; as writeable arrays (one kernel type)
        return axes, [(M if M.flags.writeable and M.flags.c_contiguous and M.dtype == np.float64
                       else np.array(M, dtype=np.float64))[..., None, :, :] for M in mats]
    k = model.m
    if axes > 1 or k < 2 or model.n != 2 * k:
        return None
    blocks = [_axis_blocks(M, k, 0.0 if i < 4 else rtol) for i, M in enumerate(mats)]
    if any(b is None for b in blocks):
        return None
    if all(np.abs(b - b[..., :1, :, :]).max() <= rtol * np.abs(b).max() for b in blocks):
        blocks = [np.ascontiguousarray(b[..., :1, :, :]) for b in blocks]
    return k, blocks


#: Steps per time block of the vector kernels (:func:`mptrack.batch._kernels.ss_kernel_blocks`).
BLOCK = 8


def time_blocks(M: np.ndarray, V: np.ndarray) -> np.ndarray:
    """The coefficients of the time-block kernels for x(k) = M(k) x(k-1) + V(k) z(k), n = 2, m = 1:
    M (8 N, 2, 2), V (8 N, 2, 1) -> C (N, 160), block i for steps 8i .. 8i+7 (s = 0..7):
    x(8i+s) = Phi(s) x(8i-1) + sum_{j <= s} Phi(s, j) V(8i+j) z(8i+j), Phi(s, j) = M(8i+s) .. M(8i+j+1),
    Phi(s) = M(8i+s) .. M(8i).  Row j < 8 of a block's (10, 16) holds the weights of z(8i+j) in the
    states as they lie in the output (entry 2s + r: component r of step s), rows 8 and 9 those of the
    two components of x(8i-1)."""
    N = M.shape[0] // BLOCK
    Ms = M[:N * BLOCK].reshape(N, BLOCK, 2, 2)
    Vs = V[:N * BLOCK].reshape(N, BLOCK, 2)
    C = np.zeros((N, BLOCK + 2, BLOCK, 2))
    Phi = np.broadcast_to(np.eye(2), (N, 2, 2))
    Psi = np.zeros((N, BLOCK, 2))                # Psi[:, j] = Phi(s, j) V(j) at the current s
    for s in range(BLOCK):
        Phi = Ms[:, s] @ Phi
        Psi[:, :s] = np.einsum("nrc,njc->njr", Ms[:, s], Psi[:, :s])
        Psi[:, s] = Vs[:, s]
        C[:, :BLOCK, s, :] = Psi
        C[:, BLOCK:, s, :] = Phi.transpose(0, 2, 1)
    return C.reshape(N, 16 * (BLOCK + 2))


@lru_cache(maxsize=16)
def _steady_blocks_of(key: bytes, q: int) -> np.ndarray:
    """:func:`_steady_blocks` of the bytes of A and Bm (read-only: it is shared)."""
    AB = np.frombuffer(key, np.float64)
    A, Bm = AB[:4 * q].reshape(q, 2, 2), AB[4 * q:].reshape(q, 2, 1)
    C = np.stack([time_blocks(np.broadcast_to(A[a], (BLOCK, 2, 2)), np.broadcast_to(Bm[a], (BLOCK, 2, 1)))
                  for a in range(q)])
    C.setflags(write=False)
    return C


def _steady_blocks(A: np.ndarray, Bm: np.ndarray) -> np.ndarray:
    """The (q, 1, 160) time-block coefficients of x = A x + B z for q axis blocks (A (q, 2, 2), Bm (q, 2,
    1)), kept for the last few steady states (a call on a small batch costs 16 microseconds; these take
    45 per axis)."""
    return _steady_blocks_of(np.ascontiguousarray(A, np.float64).tobytes()
                             + np.ascontiguousarray(Bm, np.float64).tobytes(), A.shape[0])


def _shared(P: np.ndarray, x: np.ndarray, axes: int) -> np.ndarray:
    """The covariance P (n_a, n_a) that every track has at every step, as a read-only (B, T, n, n)
    view of it (no copy); block-diagonal over the axes of :func:`per_axis`.

    The view is the one ``np.broadcast_to`` makes, built with the ndarray constructor: a few times
    cheaper than broadcast_to's general machinery, on calls whose whole set-up is 11-50 µs."""
    na = P.shape[0]
    if axes > 1:
        blocks = np.zeros((axes * na, axes * na))
        for i in range(0, axes * na, na):
            blocks[i:i + na, i:i + na] = P
        P = blocks
    P = np.ascontiguousarray(P, dtype=np.float64)
    view = np.ndarray(x.shape + x.shape[-1:], P.dtype, P, 0, (0, 0) + P.strides)
    view.setflags(write=False)
    return view


def _steady_result(x: np.ndarray, ss: SteadyState, method: str, axes: int) -> BatchFilterResult:
    """The result of a filter with the steady-state covariance Pe at every step (as its reference
    in :mod:`mptrack.linear` reports it, gaps included)."""
    return BatchFilterResult(x=x, P=_shared(ss.P_filt, x, axes), method=method, inputs={"steady": ss})


def _steady_state_filter(model, z, x0=None, out=None, *, lengths=None, steady=None, axes=1):
    bi = prepare_batch(model, z, x0, out, lengths, axes=axes, scan_z=False)
    ss = steady_argument(model, steady)
    lanes = _lane_axes(model, bi.axes, ss.A, ss.B, rtol=_STEADY_RTOL)
    if lanes is not None and lanes[0] <= K.MAX_AXES:     # rows of k axes of n = 2, m = 1: time blocks
        k, (F, _, _, _, A, Bm) = lanes
        C = _steady_blocks(A, Bm)
        flagged = launch(K.ss_kernel_blocks, bi.out.size, bi.z, bi.out, bi.z.reshape(-1), bi.out.reshape(-1),
                         A, Bm, F, C, bi.x0, bi.lengths, K.OUT_SCALE[bi.out.dtype], k > 1 and bi.axes == 1)
    else:
        c = np.ascontiguousarray
        flagged = launch(K.ss_kernel, bi.out.size, bi.z, bi.out, c(ss.A), c(ss.B), c(model.F), bi.x0,
                         bi.lengths, bi.axes, K.OUT_SCALE[bi.out.dtype])
    x = check_flagged(bi, flagged, "the steady-state filter", model=model, z=bi.z, x0=bi.x0)
    return _steady_result(x, ss, "SSKF" if ss.form == "kalman" else "SSLF", bi.axes)


def steady_state_filter(model: LinearGaussianModel, z, x0=None, out=None, *, lengths=None,
                        steady: SteadyState | None = None) -> BatchFilterResult:
    """Steady-state filter x(k/k) = A x(k-1/k-1) + B z(k) on a batch of tracks (Assimakis & Adam 2014,
    eqs. 9-10).

    Track b equals ``mptrack.linear.steady_state_filter(model, z[b], x0[b])`` (x, P, method); the state is
    carried in float64 whatever the storage dtype.

    Parameters
    ----------
    model : LinearGaussianModel
        The model shared by all tracks.
    z : array_like, shape (B, T, m)
        Measurements z(1..T) of B tracks, float64 or float32; NaN = missing.
    x0 : array_like, shape (n,) or (B, n), optional
        The prior x(0/0) (default zeros).
    out : ndarray, shape (B, T, n), optional
        C-contiguous, of z's dtype: written in place (``result.x is out``).
    lengths : array_like of int, shape (B,), optional
        Track lengths; ``x[b, lengths[b]:]`` is NaN.
    steady : SteadyState, optional
        A precomputed :func:`mptrack.riccati.steady_state` (default: solved once per model).

    Returns
    -------
    BatchFilterResult
        x the (B, T, n) states in z's dtype; P the steady-state Pe at every track and step (a read-only
        stride-0 view); inputs {"steady": the SteadyState}; method "SSKF" (or "SSLF"); the fields the
        algebra does not form are None.

    Raises
    ------
    NonFiniteError
        An infinite z, or a track that overflowed (the message names it).

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512

    Examples
    --------
    >>> import numpy as np
    >>> from mptrack import batch
    >>> from mptrack.models import assimakis_model_b
    >>> z = np.random.default_rng(0).standard_normal((1000, 50, 1))
    >>> batch.steady_state_filter(assimakis_model_b(), z).x.shape
    (1000, 50, 2)
    """
    return _steady_state_filter(model, z, x0, out, lengths=lengths, steady=steady)


@dataclass(frozen=True, eq=False)
class GainSequence:
    """The data-independent part of the Kalman filter for a model and P(0/0).

    K       (T, n, m) gains K(k), k = 1..T
    P_pred  (T, n, n) predicted covariances P(k/k-1)
    P_filt  (T, n, n) filtered covariances P(k/k) of a track with complete measurements
    P0      (n, n) the prior covariance P(0/0) they start from
    F, H    (n, n), (m, n) the model's transition and measurement matrices
    """

    K: np.ndarray
    P_pred: np.ndarray
    P_filt: np.ndarray
    P0: np.ndarray
    F: np.ndarray
    H: np.ndarray

    @property
    def T(self) -> int:
        return self.K.shape[0]

    @cached_property
    def A(self) -> np.ndarray:
        """(T, n, n) A(k) = [I - K(k) H] F: with complete measurements the filter is
        x(k/k) = A(k) x(k-1/k-1) + K(k) z(k), the time-varying form of the steady-state filter
        (Assimakis & Adam 2014, eq. 9).  Computed once, on first use."""
        n = self.F.shape[0]
        return (np.eye(n) - self.K @ self.H) @ self.F

    @cached_property
    def _memo(self) -> dict:
        """What the batch kernels derive from the sequence, kept with it (:func:`_gain_blocks`)."""
        return {}


def gain_blocks(AK: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, int]:
    """The time-block coefficients of x(k/k) = A(k) x(k-1/k-1) + K(k) z(k) for q axes of n = 2, m = 1:
    AK (T, q, 2, 2), K (T, q, 2, 1) -> (C (q, i + 1, 160), i), C[a, j] the coefficients of axis a's block
    j (:func:`time_blocks`) for j = 0..i, where block i is the first whose steps all have the last A(k)
    and K(k) of every axis: every later block is C[:, i] too (the gains reach their limit exactly in
    floating point after some tens of steps), so C holds no more than that (i = T // 8 - 1 when the
    gains have not settled by then)."""
    N = AK.shape[0] // BLOCK
    moving = np.flatnonzero((AK != AK[-1]).any(axis=(1, 2, 3)) | (K != K[-1]).any(axis=(1, 2, 3)))
    settled = min(int(moving[-1]) // BLOCK + 1 if len(moving) else 0, max(N - 1, 0))
    end = BLOCK * min(settled + 1, N)
    return np.stack([time_blocks(AK[:end, a], K[:end, a]) for a in range(AK.shape[1])]), settled


def _gain_blocks(gains: GainSequence, q: int) -> tuple[np.ndarray, int]:
    """:func:`gain_blocks` of the whole sequence with q blocks: the sequence of an n = 2, m = 1 model
    (q = 1), or of a block-diagonal model of m such axes, each axis's (q = m) or axis 0's for all
    (q = 1, the axes alike); computed once per sequence and q."""
    key = ("time blocks", q)
    if key not in gains._memo:
        m = gains.K.shape[2]
        AK, K = (gains.A[:, None], gains.K[:, None]) if m == 1 else (_axis_blocks(gains.A, m)[:, :q],
                                                                     _axis_blocks(gains.K, m)[:, :q])
        gains._memo[key] = gain_blocks(AK, K)
    return gains._memo[key]


def gain_sequence(model: LinearGaussianModel, steps: int, P0=None) -> GainSequence:
    """The Kalman gains K(1..steps) and covariances from P(0/0) = P0 (Assimakis & Adam 2014, eq. 4).

    They do not depend on the measurements, so one sequence serves every track that shares the model and
    the prior covariance; computed by the compiled Kalman core, so a shared-gain track equals
    :func:`mptrack.linear.kalman_filter` to rounding.

    Parameters
    ----------
    model : LinearGaussianModel
    steps : int
        >= 1.
    P0 : array_like, shape (n, n), optional
        Default 0.

    Returns
    -------
    GainSequence
        K, P_filt, P_pred, and A(k) = (I - K(k) H) F.

    Raises
    ------
    ResourceError
        The sequence would exceed the memory limit.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] R. E. Kalman, "A new approach to linear filtering and prediction problems", Journal of Basic
           Engineering, vol. 82, no. 1, pp. 35–45, 1960. doi:10.1115/1.3662552
    """
    require_model(model)
    steps = check_int("steps", steps, minimum=1)
    n, m = model.n, model.m
    check_allocation("steps", steps, 8.0 * steps * (n * m + 2 * n * n))
    P0 = np.zeros((n, n)) if P0 is None else np.array(check_covariance("P0", P0, n))   # a copy: P0 is kept
    c = np.ascontiguousarray
    Ks, Pp, Pf = np.empty((steps, n, m)), np.empty((steps, n, n)), np.empty((steps, n, n))
    # an overflow leaves NaN, reported by require_finite below
    K.gain_loop(c(model.F), c(model.H), c(model.Q), c(model.R), P0.copy(), Ks, Pp, Pf)
    result = GainSequence(K=Ks, P_pred=Pp, P_filt=Pf, P0=P0, F=np.array(model.F), H=np.array(model.H))
    require_finite("the Kalman gain sequence", result, model=model, P0=P0)
    return result


def _kalman_filter(model, z, x0=None, P0=None, out=None, *, lengths=None, gains=None, axes=1):
    bi = prepare_batch(model, z, x0, out, lengths, axes=axes, scan_z=False)
    T = bi.z.shape[1]
    if gains is None:
        gains = gain_sequence(model, T, P0)
    elif not isinstance(gains, GainSequence):
        raise ParameterError(f"gains: expected a GainSequence, got {type(gains).__name__}")
    elif gains.K.shape[1:] != (model.n, model.m) or gains.T < T:
        raise ShapeError(f"gains: expected at least {T} gains of shape ({model.n}, {model.m}), "
                         f"got K of shape {gains.K.shape}")
    elif P0 is not None:
        raise ParameterError("P0: give P0 or gains (which already fix P0), not both")
    lanes = _lane_axes(model, bi.axes, gains.A[:T], gains.K[:T], gains.P_filt[:T], gains.P0)
    if lanes is not None and lanes[0] <= K.MAX_AXES:     # rows of k axes of n = 2, m = 1: time blocks
        blocks = lanes[1]
        C, settled = _gain_blocks(gains, blocks[0].shape[0])
        flagged = launch(K.kf_kernel_blocks, bi.out.size, bi.z, bi.out, bi.z.reshape(-1), bi.out.reshape(-1),
                         *blocks, C, settled, bi.x0, bi.lengths, K.OUT_SCALE[bi.out.dtype])
    else:
        c = np.ascontiguousarray
        flagged = launch(K.kf_kernel, bi.out.size, bi.z, bi.out, c(model.F), c(model.H), c(model.Q), c(model.R),
                         c(gains.A), c(gains.K), c(gains.P_filt), c(gains.P0), bi.x0, bi.lengths, bi.axes,
                         K.OUT_SCALE[bi.out.dtype])
    x = check_flagged(bi, flagged, "the Kalman filter", model=model, z=bi.z, x0=bi.x0, P0=gains.P0)
    return BatchFilterResult(x=x, P=None, method="KF", inputs={"gains": gains})


def kalman_filter(model: LinearGaussianModel, z, x0=None, P0=None, out=None, *, lengths=None,
                  gains: GainSequence | None = None) -> BatchFilterResult:
    """Kalman filter on a batch of tracks with one shared gain sequence (Assimakis & Adam 2014, eq. 4).

    All tracks share the model and P0, so the gains K(k) are computed once (:func:`gain_sequence`) and
    applied to every track; a track whose measurement has a NaN component leaves the shared sequence
    there and runs its own covariance recursion (NaN components skipped), exactly as
    :func:`mptrack.linear.kalman_filter`.

    Parameters
    ----------
    model : LinearGaussianModel
        The model shared by all tracks.
    z : array_like, shape (B, T, m)
        Measurements z(1..T) of B tracks, float64 or float32; NaN = missing.
    x0 : array_like, shape (n,) or (B, n), optional
        The prior x(0/0) (default zeros).
    P0 : array_like, shape (n, n), optional
        The shared prior covariance (default 0).
    out : ndarray, shape (B, T, n), optional
        C-contiguous, of z's dtype: written in place (``result.x is out``).
    lengths : array_like of int, shape (B,), optional
        Track lengths; ``x[b, lengths[b]:]`` is NaN.
    gains : GainSequence, optional
        A precomputed :func:`gain_sequence`.

    Returns
    -------
    BatchFilterResult
        x the (B, T, n) states; P None (a track with a missing component has its own covariances; the
        shared sequence, the covariance of every complete track, is in ``inputs["gains"]``); method "KF".

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] R. E. Kalman, "A new approach to linear filtering and prediction problems", Journal of Basic
           Engineering, vol. 82, no. 1, pp. 35–45, 1960. doi:10.1115/1.3662552
    """
    return _kalman_filter(model, z, x0, P0, out, lengths=lengths, gains=gains)


def _fir_filter(model, z, out=None, *, lengths=None, eps=1e-3, norm=2, M=None, steady=None, axes=1):
    bi = prepare_batch(model, z, None, out, lengths, axes=axes)
    ss = steady_argument(model, steady)
    check_order_rule(eps, norm)
    M = fir_order(ss.A, eps, norm) if M is None else check_int("M", M, minimum=1)
    M = min(M, bi.z.shape[1])         # the window never reaches further back than the T steps
    C = np.ascontiguousarray(coefficients_unchecked(ss.A, ss.B, M))
    bad = np.zeros(bi.z.shape[0], dtype=np.int64)
    launch(K.fir_kernel, bi.out.size * M, bi.z, bi.out, C, bi.lengths, bi.axes, bad)
    if bad.any():
        b = int(np.flatnonzero(bad)[0])
        raise NonFiniteError(f"z: the FIR filter needs every measurement; track {b} has NaN at time "
                             f"index {bad[b] - 1} (use steady_state_filter, which predicts through gaps)")
    x = check_finite_out(bi, "the FIR filter", model=model, z=bi.z)
    return _steady_result(x, ss, "FIR", bi.axes)


def fir_filter(model: LinearGaussianModel, z, out=None, *, lengths=None, eps: float = 1e-3, norm=2,
               M: int | None = None, steady: SteadyState | None = None) -> BatchFilterResult:
    """FIR steady-state filter x(k/k) = sum_{j<M} A^j B z(k-j) on a batch (Assimakis & Adam 2014,
    eq. 22).

    The warm-up k < M uses the measurements available so far (the reference's ``warmup="truncate"``);
    track b equals ``mptrack.linear.fir_filter(model, z[b], M=M)``.

    Parameters
    ----------
    model : LinearGaussianModel
        The model shared by all tracks.
    z : array_like, shape (B, T, m)
        Measurements, complete inside each track's length.
    out : ndarray, shape (B, T, n), optional
        C-contiguous, of z's dtype: written in place (``result.x is out``).
    lengths : array_like of int, shape (B,), optional
        Track lengths; ``x[b, lengths[b]:]`` is NaN.
    eps : float, optional
    norm : optional
        The order rule: the smallest M with ||A^M|| < eps in the matrix ``norm``.
    M : int, optional
        The order.
    steady : SteadyState, optional
        A precomputed :func:`mptrack.riccati.steady_state` (default: solved once per model).

    Returns
    -------
    BatchFilterResult
        As :func:`steady_state_filter`, method "FIR".

    Raises
    ------
    NonFiniteError
        NaN inside a track's length.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    return _fir_filter(model, z, out, lengths=lengths, eps=eps, norm=norm, M=M, steady=steady)


def predict(model: LinearGaussianModel, x, steps: int = 1, out=None) -> np.ndarray:
    """N-step prediction x(k+N/k) = F^N x(k/k) of a batch of filtered states.

    Parameters
    ----------
    model : LinearGaussianModel
    x : array_like, shape (B, T, n)
        Filtered states (a batch filter's ``result.x``), or (B, T, axes n) from :func:`per_axis` with an
        axis model (each axis block predicted with F^N).
    steps : int, optional
        The horizon N >= 1 (steps of model.dt).
    out : ndarray, optional
        C-contiguous output of x's shape and dtype (may be x itself).

    Returns
    -------
    ndarray
    """
    require_model(model)
    steps = check_int("steps", steps, minimum=1)
    if isinstance(x, BatchFilterResult):
        raise ParameterError("x: expected the (B, T, n) states, got a BatchFilterResult (pass its .x)")
    x = _to_array("x", x)
    if x.ndim != 3 or x.shape[2] == 0 or x.shape[2] % model.n:
        raise ShapeError(f"x: expected shape (B, T, axes * {model.n}), got shape {x.shape}")
    axes = x.shape[2] // model.n
    xs = as_batch("x", x, x.shape[2])
    out = np.empty_like(xs) if out is None else check_out(out, xs.shape, xs.dtype, None if out is x else xs)
    with np.errstate(all="ignore"):
        FN = np.linalg.matrix_power(model.F, steps)
    require_finite("F^steps", FN, model=model, steps=steps)
    launch(K.matvec_kernel, out.size, xs, out, np.ascontiguousarray(FN), axes)
    if not np.isnan(xs).any():
        require_finite("the prediction", out, model=model, x=xs, steps=steps)
    return out


_PER_AXIS: dict[Callable, Callable[..., BatchFilterResult]] = {
    steady_state_filter: _steady_state_filter,
    kalman_filter: _kalman_filter,
    fir_filter: _fir_filter,
}


def per_axis(run: Callable[..., BatchFilterResult], axis_model: LinearGaussianModel, z, *args,
             **kwargs) -> BatchFilterResult:
    """Run a batch filter per axis with an axis model (model B; Assimakis & Adam 2014, eqs. 17-18).

    The axes run as extra tracks of the same kernel, without copying z; the result equals
    ``mptrack.linear.per_axis(reference, axis_model, z[b], ...)`` track by track.

    Parameters
    ----------
    run : callable
        :func:`steady_state_filter`, :func:`kalman_filter` or :func:`fir_filter`.
    axis_model : LinearGaussianModel
        The one-axis model (n_a, m_a), e.g. ``assimakis_model_b()``.
    z : array_like, shape (B, T, axes m_a)
        Columns axis by axis [z_x, z_y, ...].
    *args, **kwargs
        The other arguments of ``run`` (x0 of width axes n_a).

    Returns
    -------
    BatchFilterResult
        x (B, T, axes n_a), axis by axis (P, when ``run`` gives it, block-diagonal).

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    impl = _PER_AXIS.get(run) if callable(run) else None
    if impl is None:
        raise ParameterError("run: expected mptrack.batch.steady_state_filter, kalman_filter or fir_filter")
    require_model(axis_model, "axis_model")
    shape = _to_array("z", z).shape
    if len(shape) != 3 or shape[2] == 0 or shape[2] % axis_model.m:
        raise ShapeError(f"z: expected shape (B, T, axes * {axis_model.m}), got shape {shape}")
    return impl(axis_model, z, *args, axes=shape[2] // axis_model.m, **kwargs)

