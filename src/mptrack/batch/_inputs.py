"""Validation of the batch engine's arguments (shapes, dtypes, ``lengths``, ``out``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._core.finiteness import _overflow
from .._core.float_scan import any_nonfinite
from .._core.threads import launch
from .._core.validation import as_array, as_vector, check_allocation, check_values, _to_array
from ..errors import DTypeError, ParameterError, ShapeError
from ..models import LinearGaussianModel

__all__ = ["BatchInputs", "prepare_batch", "as_batch", "check_out", "launch", "check_finite_out", "check_flagged"]

_FLOATS = (np.dtype(np.float64), np.dtype(np.float32))

@dataclass(frozen=True, eq=False)
class BatchInputs:
    z: np.ndarray        # (B, T, axes * m) C-contiguous float64/float32
    out: np.ndarray      # (B, T, axes * n) same dtype
    x0: np.ndarray       # (B, axes * n) float64
    lengths: np.ndarray  # (B,) int64 in [0, T]
    axes: int


def as_batch(name: str, value, width: int, *, scan: bool = True) -> np.ndarray:
    """A (B, T, width) float32/float64 C-contiguous array; other real dtypes become float64.
    NaN (missing) is allowed, infinity is not: refused here, or with ``scan=False`` by the caller's
    kernel, which flags it while it reads the array (then :func:`check_flagged`)."""
    arr = _to_array(name, value)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise DTypeError(f"{name}: expected real numbers (float64 or float32), got dtype {arr.dtype}")
    if arr.ndim != 3 or arr.shape[2] != width:
        raise ShapeError(f"{name}: expected shape (B, T, {width}), got shape {arr.shape}")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ShapeError(f"{name}: expected at least one track and one time step, got shape {arr.shape}")
    if arr.dtype not in _FLOATS:
        arr = arr.astype(np.float64)
    if scan:
        check_values(name, arr, allow_nan=True)  # refuses +-Inf: in z's dtype, no copy
    return np.ascontiguousarray(arr)


def check_finite_out(bi: "BatchInputs", what: str, **inputs) -> np.ndarray:
    """The output-finiteness policy for a batch: rows inside each track's length must be finite
    (after it they are NaN by contract).  Scanned in one parallel pass in the output's dtype
    (min and max over the whole output on one thread, and a masked copy for ragged batches,
    cost more than the filter itself)."""
    out = bi.out
    track = out.shape[1] * out.shape[2]
    starts = np.arange(out.shape[0], dtype=np.int64) * track
    if any_nonfinite(out, starts, bi.lengths * out.shape[2]):
        raise _overflow(what, inputs, None)
    return out


def check_flagged(bi: "BatchInputs", flagged: int, what: str, **inputs) -> np.ndarray:
    """The output of a kernel that checks as it streams (:mod:`mptrack.batch._kernels`): ``flagged``
    tracks may hold an infinite measurement or a non-finite state.  When 0, nothing more is read;
    else the shared checks find and name it -- an infinity in z (NonFiniteError naming z), else the
    filter's overflow (:func:`check_finite_out`) -- or find nothing (a flag is not a verdict)."""
    if flagged:
        check_values("z", bi.z, allow_nan=True)
        check_finite_out(bi, what, **inputs)
    return bi.out


def check_out(out, shape: tuple, dtype, source: np.ndarray | None) -> np.ndarray:
    """``out`` must be a writeable C-contiguous array of this shape and dtype, not overlapping ``source``."""
    if not isinstance(out, np.ndarray):
        raise DTypeError(f"out: expected a numpy array, got {type(out).__name__}")
    if out.shape != tuple(shape):
        raise ShapeError(f"out: expected shape {tuple(shape)}, got shape {out.shape}")
    if out.dtype != dtype:
        raise DTypeError(f"out: expected dtype {dtype} (that of the input), got dtype {out.dtype}")
    if not out.flags.c_contiguous or not out.flags.writeable:
        raise ShapeError("out: must be a writeable C-contiguous array")
    if source is not None and np.may_share_memory(out, source):
        raise ShapeError("out: must not overlap the input")
    return out


def prepare_batch(model, z, x0, out, lengths, *, axes: int = 1,
                  model_type: type = LinearGaussianModel, scan_z: bool = True) -> BatchInputs:
    """Check and normalise the arguments every batch filter takes.

    z        (B, T, axes * model.m) measurements; NaN marks a missing value
    x0       None (zeros), (axes * n,) for every track, or (B, axes * n)
    out      None (allocated) or a C-contiguous (B, T, axes * n) array of z's dtype
    lengths  None (all T) or (B,) integers in [0, T]: track b uses z[b, :lengths[b]]
             and gets NaN after it
    scan_z   False for a kernel that flags an infinite z itself (then :func:`check_flagged`)
    """
    if not isinstance(model, model_type):
        raise ParameterError(f"model: expected a {model_type.__name__}, got {type(model).__name__}")
    n, m = axes * model.n, axes * model.m
    z = as_batch("z", z, m, scan=scan_z)
    B, T = z.shape[:2]
    if x0 is not None:
        x0 = _to_array("x0", x0)
    if x0 is None:
        x0 = np.zeros((B, n))
    elif x0.ndim == 1:
        # a writeable copy: with B = 1 ascontiguousarray would keep the read-only broadcast view,
        # which numba types differently (a second compilation of every kernel)
        x0 = np.array(np.broadcast_to(as_vector("x0", x0, n), (B, n)))
    else:
        x0 = np.ascontiguousarray(as_array("x0", x0, shape=(B, n)))
    if lengths is None:
        lengths = np.full(B, T, dtype=np.int64)
    else:
        raw = np.asarray(lengths)
        if raw.dtype.kind not in "iu":
            raise DTypeError(f"lengths: expected integers, got dtype {raw.dtype}")
        if raw.shape != (B,):
            raise ShapeError(f"lengths: expected shape ({B},), got shape {raw.shape}")
        if raw.size and (raw.min() < 0 or raw.max() > T):
            raise ParameterError(f"lengths: expected values in [0, {T}], "
                                 f"got min {raw.min()}, max {raw.max()}")
        lengths = np.ascontiguousarray(raw, dtype=np.int64)
    if out is None:
        check_allocation("z", f"shape {z.shape}", float(B) * T * n * z.dtype.itemsize)
        out = np.empty((B, T, n), dtype=z.dtype)
    else:
        out = check_out(out, (B, T, n), z.dtype, z)
    return BatchInputs(z=z, out=out, x0=x0, lengths=lengths, axes=axes)
