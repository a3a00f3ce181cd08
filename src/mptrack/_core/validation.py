"""Argument checks at the public boundary.

Each helper takes the argument's *name* so that error messages say which argument was wrong, what was
expected and what was received.  The checks of data files and tables are in :mod:`.data_checks`, the
finiteness of results and the relabelling of errors with the caller's names in :mod:`.finiteness`.
"""

from __future__ import annotations

import math
import numbers
import os
from pathlib import Path

import numpy as np

from ..errors import (
    DTypeError,
    NonFiniteError,
    NotPositiveDefiniteError,
    NotSymmetricError,
    ParameterError,
    ResourceError,
    ShapeError,
    UnknownNameError,
)
from .finiteness import _finite_data

__all__ = ["as_array", "check_values", "broadcast_shape", "as_matrix", "as_vector", "as_sequence", "check_covariance", "check_positive", "check_int", "check_rng", "check_bool", "lookup", "check_path", "as_real", "check_allocation", "memory_limit", "check_record", "frozen", "LATITUDE", "LONGITUDE"]

# Valid ranges of geodetic coordinates, as keyword arguments of as_array.
LATITUDE = dict(low=-90.0, high=90.0, unit="degrees")
LONGITUDE = dict(low=-180.0, high=180.0, unit="degrees")


def _shape_text(shape: tuple) -> str:
    return "(" + ", ".join("?" if s is None else str(s) for s in shape) + (",)" if len(shape) == 1 else ")")


def as_array(name: str, value, *, ndim: int | None = None, shape: tuple | None = None,
             finite: bool = True, allow_nan: bool = False, low: float = -math.inf,
             high: float = math.inf, unit: str = "") -> np.ndarray:
    """Convert ``value`` to a float64 array and check its shape and values.

    ``shape`` may contain ``None`` for free sizes.  ``allow_nan`` lets NaN through
    (missing measurements) while still rejecting infinities.  ``low``/``high``
    bound the values (inclusive; NaN let through by ``allow_nan`` is not compared);
    ``unit`` is appended to the range in the message ("degrees").  A value out of
    range raises :class:`ParameterError`.
    """
    arr = _to_array(name, value)
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise DTypeError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float64, copy=False)
    if shape is not None:
        ndim = len(shape)
    if ndim is not None and arr.ndim != ndim:
        expected = _shape_text(shape) if shape is not None else f"{ndim}-D"
        raise ShapeError(f"{name}: expected shape {expected}, got shape {arr.shape}")
    if shape is not None:
        for want, got in zip(shape, arr.shape):
            if want is not None and want != got:
                raise ShapeError(f"{name}: expected shape {_shape_text(shape)}, got shape {arr.shape}")
    check_values(name, arr, finite=finite, allow_nan=allow_nan, low=low, high=high, unit=unit)
    return arr


def check_values(name: str, arr: np.ndarray, *, finite: bool = True, allow_nan: bool = False,
                 low: float = -math.inf, high: float = math.inf, unit: str = "") -> None:
    """The value checks of :func:`as_array` on a real array in its own dtype (a float32 array is
    not copied to float64 to be checked)."""
    bounded = low > -math.inf or high < math.inf
    if finite and not bounded and _scannable(arr):   # large float data: one parallel pass
        from .float_scan import any_infinite, any_nonfinite
        if (any_infinite if allow_nan else any_nonfinite)(arr):
            _check_values(name, arr, finite, allow_nan, low, high, unit)
    elif (finite or bounded) and arr.size and not _extremes_ok(_finite_data(arr), low, high, finite):
        _check_values(name, arr, finite, allow_nan, low, high, unit)


def _scannable(arr: np.ndarray) -> bool:
    """Large enough for the compiled scan of :mod:`mptrack._core.float_scan` to pay (and laid out for it)."""
    return arr.size >= (1 << 20) and arr.dtype in (np.float64, np.float32) and arr.flags.c_contiguous


def _extremes_ok(arr: np.ndarray, low: float, high: float, finite: bool) -> bool:
    """Fast acceptance test from the smallest and largest value (NaN propagates into both).

    Two reductions instead of a boolean temporary; a single value is read directly,
    which keeps scalar calls at a fraction of a microsecond.  False means "look closer"
    (always when ``finite`` and a NaN or infinity is present, even if NaN is allowed).
    """
    if arr.size == 1:
        smallest = largest = float(arr.reshape(-1)[0])
    else:
        smallest, largest = float(arr.min()), float(arr.max())
    if finite and not (math.isfinite(smallest) and math.isfinite(largest)):
        return False
    return low <= smallest and largest <= high


def _check_values(name: str, arr: np.ndarray, finite: bool, allow_nan: bool, low: float, high: float,
                  unit: str) -> None:
    """Raise for the first non-finite, then the first out-of-range value of ``arr`` (if any)."""
    if finite:
        bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
        if bad.any():
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            what = "infinite" if allow_nan else "non-finite"
            raise NonFiniteError(f"{name}: contains {what} value {float(arr[idx])!r} at index {idx}")
    if low == -math.inf and high == math.inf:
        return
    outside = (arr < low) | (arr > high)
    if outside.any():
        idx = tuple(int(i) for i in np.argwhere(outside)[0])
        unit = f" {unit}" if unit else ""
        where = f" at index {idx}" if arr.ndim else ""
        raise ParameterError(f"{name}: expected values in [{low:g}, {high:g}]{unit}, "
                             f"got {float(arr[idx])!r}{where}")


def broadcast_shape(**arrays: np.ndarray) -> tuple:
    """The shape that the named arrays broadcast to (NumPy rules).

    Raises :class:`ShapeError` naming the first argument whose shape does not
    broadcast with those of the arguments before it.  Arguments that are all
    scalars or of one shape (the common case) cost no NumPy call.
    """
    shapes = {arr.shape for arr in arrays.values()} - {()}
    if len(shapes) <= 1:
        return shapes.pop() if shapes else ()
    shape: tuple = ()
    before = []
    for name, arr in arrays.items():
        try:
            shape = np.broadcast_shapes(shape, arr.shape)
        except ValueError:
            raise ShapeError(f"{name}: expected a shape that broadcasts with {shape} (the shape of "
                             f"{', '.join(before)}), got shape {arr.shape}") from None
        before.append(name)
    return shape


def _to_array(name: str, value) -> np.ndarray:
    """np.asarray with NumPy's conversion errors (ragged lists, ...) turned into ours, and the size
    checked before anything reads the values: an argument whose float64 copy would exceed
    :func:`memory_limit` (a broadcast view of 10^12 rows) is a ResourceError, not minutes of scanning
    followed by a MemoryError."""
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError) as exc:
        raise DTypeError(f"{name}: cannot be converted to an array of numbers ({exc})") from None
    if arr.size > _SMALL_ARRAY:
        check_allocation(name, f"an array of shape {arr.shape}", 8.0 * arr.size)
    return arr


#: Arrays up to this many values skip the size check (it matters only for huge ones).
_SMALL_ARRAY = 1 << 16


def as_matrix(name: str, value, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """A finite 2-D float matrix with at least one row and column; a scalar is a 1x1 matrix."""
    arr = _to_array(name, value)
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    arr = as_array(name, arr, shape=(rows, cols))
    if 0 in arr.shape:
        raise ShapeError(f"{name}: expected a non-empty matrix, got shape {arr.shape}")
    return arr


def as_vector(name: str, value, size: int | None = None, *, low: float = -math.inf,
              high: float = math.inf) -> np.ndarray:
    """A finite 1-D float array (a scalar is a vector of one), values in [low, high]."""
    arr = _to_array(name, value)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    return as_array(name, arr, shape=(size,), low=low, high=high)


def as_sequence(name: str, value, width: int, *, allow_nan: bool = False) -> np.ndarray:
    """A measurement sequence of shape (T, width); a 1-D input is accepted when width == 1."""
    arr = _to_array(name, value)
    if arr.ndim == 1 and width == 1:
        arr = arr[:, None]
    arr = as_array(name, arr, shape=(None, width), allow_nan=allow_nan)
    if arr.shape[0] == 0:
        raise ShapeError(f"{name}: expected at least one time step, got shape {arr.shape}")
    return arr


def frozen(arr) -> np.ndarray:
    """A read-only float64 copy of ``arr``: the arrays of the immutable model records."""
    arr = np.array(arr, dtype=np.float64, copy=True)
    arr.setflags(write=False)
    return arr


def check_covariance(name: str, value, size: int | None = None, *, definite: bool = False,
                     rtol: float = 1e-9) -> np.ndarray:
    """A symmetric positive semi-definite (or definite) covariance matrix.

    Symmetry is checked to ``rtol`` relative to the largest entry; the returned
    matrix is exactly symmetrised.  Definiteness uses the eigenvalues with a
    tolerance scaled to the matrix norm.
    """
    mat = as_matrix(name, value, size, size)
    if mat.shape[0] != mat.shape[1]:
        raise ShapeError(f"{name}: expected a square matrix, got shape {mat.shape}")
    scale = max(float(np.max(np.abs(mat))), np.finfo(float).tiny)
    asym = float(np.max(np.abs(mat - mat.T)))
    if asym > rtol * scale:
        raise NotSymmetricError(f"{name}: must be symmetric, max |{name} - {name}^T| = {asym:.3g}")
    mat = 0.5 * mat + 0.5 * mat.T      # not 0.5 (mat + mat.T): entries beyond 9e307 would overflow
    try:
        eig = np.linalg.eigvalsh(mat)
    except np.linalg.LinAlgError:  # entries near the float range: LAPACK's scaling overflows
        raise NonFiniteError(f"{name}: entries up to {scale:.3g} are too large to check its definiteness; "
                             "rescale the units") from None
    tol = 1e-12 * scale * mat.shape[0]
    if definite and eig[0] <= tol:
        raise NotPositiveDefiniteError(
            f"{name}: must be positive definite, smallest eigenvalue is {eig[0]:.3g}")
    if eig[0] < -1e-9 * scale:
        raise NotPositiveDefiniteError(
            f"{name}: must be positive semi-definite, smallest eigenvalue is {eig[0]:.3g}")
    return mat


def as_real(name: str, value, *, low: float = -math.inf, high: float = math.inf, unit: str = "",
            infinite: bool = False) -> float:
    """A finite real scalar (a Python or NumPy number, or a 0-d array) in [low, high].

    Strings, complex numbers, None and arrays of other sizes are refused with the argument's name;
    this is the one check of scalar parameters (heights, frequencies, membership breakpoints).
    ``infinite`` lets +-inf through (a fuzzy set's open shoulder), never NaN.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.ndarray)):
        raise ParameterError(f"{name}: expected a real number, got {value!r}")
    if infinite and isinstance(value, numbers.Real) and math.isinf(value):
        return float(value)
    return float(as_array(name, value, ndim=0, low=low, high=high, unit=unit))


def check_positive(name: str, value, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(f"{name}: expected a real number, got {value!r}")
    value = float(value)
    ok = value >= 0 if allow_zero else value > 0
    if not np.isfinite(value) or not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ParameterError(f"{name}: expected a finite number {bound}, got {value!r}")
    return value


def check_int(name: str, value, *, minimum: int | None = None, maximum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ParameterError(f"{name}: expected an integer, got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ParameterError(f"{name}: expected an integer >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise ParameterError(f"{name}: expected an integer <= {maximum}, got {value}")
    return value


def check_path(name: str, value) -> Path:
    """A file-system path (str or os.PathLike) as a Path; anything else is a ParameterError."""
    if isinstance(value, (str, os.PathLike)) and not isinstance(value, bytes) and str(value) and \
            "\x00" not in str(value):
        return Path(value)
    raise ParameterError(f"{name}: expected a file path (str or pathlib.Path), got {value!r}")


def lookup(name: str, value, registry: dict, *, what: str = "name", fold=str.lower):
    """``registry[fold(value)]``: the entry of a name looked up in a registry (filters, models, ...);
    anything else (not a string, or unknown) is an UnknownNameError naming ``name`` and the known names."""
    key = fold(value) if isinstance(value, str) else None
    if key not in registry:
        raise UnknownNameError(f"{name}: unknown {what} {value!r}; known: {', '.join(map(str, registry))}")
    return registry[key]


def check_bool(name: str, value) -> bool:
    """True or False (a NumPy bool too); "yes", 1 or None are not flags."""
    if not isinstance(value, (bool, np.bool_)):
        raise ParameterError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def check_rng(rng, name: str = "rng") -> np.random.Generator:
    """A numpy.random.Generator (randomness only through explicit generators)."""
    if not isinstance(rng, np.random.Generator):
        raise ParameterError(f"{name}: expected a numpy.random.Generator, got {type(rng).__name__}")
    return rng


def memory_limit() -> int:
    """Bytes one call may allocate: ``MPTRACK_MAX_BYTES``, else half the physical memory, or half the
    process's address-space limit (``ulimit -v``) when that is lower (the process's own mappings,
    the interpreter and the compiled code, take part of it)."""
    env = os.environ.get("MPTRACK_MAX_BYTES")
    if env:
        return int(float(env))
    try:
        limit = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        limit = 8 * 2**30
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft != resource.RLIM_INFINITY:
            limit = min(limit, soft // 2)
    except (ImportError, ValueError, OSError):  # pragma: no cover - not POSIX
        pass
    return limit


def _bytes_text(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} EiB"  # pragma: no cover


def check_allocation(name: str, value, nbytes: float) -> None:
    """Refuse, before allocating, a result of ``nbytes`` bytes that argument ``name`` (= value, or a
    text describing it) asks for when it exceeds :func:`memory_limit` (estimate first, instead of a
    MemoryError or a machine that swaps)."""
    limit = memory_limit()
    if nbytes > limit:
        shown = value if isinstance(value, str) else repr(value)
        raise ResourceError(f"{name}: {shown} needs {_bytes_text(nbytes)} of memory, more than the limit of "
                            f"{_bytes_text(limit)} (set MPTRACK_MAX_BYTES to change it, or work in chunks)")


def check_record(name: str, record, fields=("x", "P", "x_pred", "P_pred")) -> None:
    """The array fields of a result record passed in as an argument must be finite, non-empty arrays
    with a leading time axis and agreeing sizes: x (T, n), P (T, n, n)."""
    size = None
    for field in fields:
        value = getattr(record, field, None)
        if value is None and field not in ("x", "P"):      # x, P are always there; predictions may not be
            continue
        label = f"{name}.{field}"
        arr = _to_array(label, value)
        want = 2 if field.startswith("x") else 3
        if not isinstance(value, np.ndarray) or arr.ndim != want or 0 in arr.shape:
            raise ShapeError(f"{label}: expected a non-empty {want}-D array, got {type(value).__name__} "
                             f"of shape {np.shape(arr)}")
        as_array(label, _finite_data(arr))
        size = size or arr.shape[:2]
        expected = size if want == 2 else size + size[1:]
        if arr.shape != expected:
            raise ShapeError(f"{label}: expected shape {expected} (T steps of an n-state), got {arr.shape}")
