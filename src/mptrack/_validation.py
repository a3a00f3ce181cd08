"""Input validation at the public boundary.

Each helper takes the argument's *name* so that error messages say which
argument was wrong, what was expected and what was received.
"""

from __future__ import annotations

import functools
import inspect
import math
import numbers
import os
from pathlib import Path

import numpy as np

from .errors import (
    DTypeError,
    MptrackError,
    NonFiniteError,
    NotPositiveDefiniteError,
    NotSymmetricError,
    ParameterError,
    ResourceError,
    ShapeError,
)

__all__ = [
    "as_array",
    "broadcast_shape",
    "as_matrix",
    "as_vector",
    "as_sequence",
    "check_covariance",
    "check_positive",
    "check_int",
    "check_outputs",
    "as_real",
    "check_allocation",
    "memory_limit",
    "finite_result",
    "require_finite",
    "check_record",
]


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
    bounded = low > -math.inf or high < math.inf
    if (finite or bounded) and arr.size and not _extremes_ok(arr, low, high, finite):
        _check_values(name, arr, finite, allow_nan, low, high, unit)
    return arr


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
            raise NonFiniteError(f"{name}: contains {what} value {arr[idx]!r} at index {idx}")
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
    """np.asarray with NumPy's conversion errors (ragged lists, ...) turned into ours."""
    try:
        return np.asarray(value)
    except (ValueError, TypeError) as exc:
        raise DTypeError(f"{name}: cannot be converted to an array of numbers ({exc})") from None


def as_matrix(name: str, value, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """A finite 2-D float matrix with at least one row and column; a scalar is a 1x1 matrix."""
    arr = _to_array(name, value)
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    arr = as_array(name, arr, shape=(rows, cols))
    if 0 in arr.shape:
        raise ShapeError(f"{name}: expected a non-empty matrix, got shape {arr.shape}")
    return arr


def as_vector(name: str, value, size: int | None = None) -> np.ndarray:
    arr = _to_array(name, value)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    return as_array(name, arr, shape=(size,))


def as_sequence(name: str, value, width: int, *, allow_nan: bool = False) -> np.ndarray:
    """A measurement sequence of shape (T, width); a 1-D input is accepted when width == 1."""
    arr = _to_array(name, value)
    if arr.ndim == 1 and width == 1:
        arr = arr[:, None]
    arr = as_array(name, arr, shape=(None, width), allow_nan=allow_nan)
    if arr.shape[0] == 0:
        raise ShapeError(f"{name}: expected at least one time step, got shape {arr.shape}")
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
    mat = 0.5 * (mat + mat.T)
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


def memory_limit() -> int:
    """Bytes one call may allocate: ``MPTRACK_MAX_BYTES`` or half the physical memory."""
    env = os.environ.get("MPTRACK_MAX_BYTES")
    if env:
        return int(float(env))
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 8 * 2**30


def _bytes_text(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} EiB"  # pragma: no cover


def check_allocation(name: str, value, nbytes: float) -> None:
    """Refuse, before allocating, a result of ``nbytes`` bytes that argument ``name`` (= value)
    asks for when it exceeds :func:`memory_limit` (estimate first, instead of a MemoryError or
    a machine that swaps)."""
    limit = memory_limit()
    if nbytes > limit:
        raise ResourceError(f"{name}: {value!r} needs {_bytes_text(nbytes)} of memory, more than the limit of "
                            f"{_bytes_text(limit)} (set MPTRACK_MAX_BYTES to change it, or work in chunks)")


# --- output finiteness -------------------------------------------------------------------------

def _finite_data(arr: np.ndarray) -> np.ndarray:
    """The distinct data of a broadcast view (a stride of 0 repeats values: look at one copy)."""
    if arr.ndim and 0 in arr.strides:
        arr = arr[tuple(0 if s == 0 else slice(None) for s in arr.strides)]
    return arr


def _leaves(value, depth: int = 0):
    """The numbers inside an argument or result: arrays and scalars, looked for in tuples, lists
    and dataclass records (models, results) two levels deep."""
    if isinstance(value, (bool, np.bool_, str)) or value is None:
        return
    if isinstance(value, (numbers.Real, np.ndarray)):
        arr = np.asarray(value)
        if arr.dtype.kind in "iufc" and arr.size:
            yield _finite_data(arr)
    elif depth < 2 and isinstance(value, (tuple, list)):
        for v in value:
            yield from _leaves(v, depth + 1)
    elif depth < 2 and hasattr(value, "__dataclass_fields__"):
        for f in value.__dataclass_fields__:
            yield from _leaves(getattr(value, f), depth + 1)


def _all_finite(value) -> bool:
    # min and max propagate NaN and show infinities: two reductions, no boolean temporary
    return all(bool(np.isfinite(a.min()) and np.isfinite(a.max())) if a.dtype.kind == "f"
               else bool(np.isfinite(a).all()) for a in _leaves(value))


def _has_nan(value) -> bool:
    return any(bool(np.isnan(a).any()) for a in _leaves(value))


def _magnitude(value) -> float:
    """The largest finite |number| inside an argument (arrays, models, results, scalars)."""
    sizes = [np.abs(a.real if a.dtype.kind == "c" else a) for a in _leaves(value)]
    sizes = [float(a[np.isfinite(a)].max()) for a in sizes if np.isfinite(a).any()]
    return max(sizes, default=0.0)


def require_finite(what: str, value, **inputs) -> None:
    """Raise :class:`NonFiniteError` when ``value`` (an array, a result record) holds NaN or
    infinity although ``inputs`` (name=argument) were finite: an overflow in the computation.
    The message names the input of largest magnitude, the likely cause."""
    if not _all_finite(value):
        raise _overflow(what, inputs, None)


def _overflow(what: str, inputs: dict, cause) -> NonFiniteError:
    sizes = sorted(((_magnitude(v), k) for k, v in inputs.items()), reverse=True)
    named = ", ".join(f"|{k}| up to {m:.3g}" for m, k in sizes if m > 0) or "no large values"
    first = sizes[0][1] if sizes else "inputs"
    why = f" ({type(cause).__name__}: {cause})" if cause is not None else ""
    return NonFiniteError(
        f"{first}: {what} overflowed the float64 range (a NaN or infinity appeared from finite input"
        f"{why}); the inputs hold {named}; rescale them (e.g. metres -> km) or check the model")


_BREAKDOWNS = (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError)


def finite_result(what: str):
    """Decorator of the output-finiteness policy (docs/design.md, "Finite answers"):
    the wrapped public function's result (arrays, result records) must be finite; when it is not,
    or when the computation breaks down inside a compiled kernel (a LinAlgError on infinities,
    a division by zero), a :class:`NonFiniteError` names the argument of largest magnitude.
    Arguments are validated by the function itself first (their errors pass through).  A NaN
    result is let through when an argument holds NaN (missing data, where the function allows it)."""
    def wrap(fn):
        signature = inspect.signature(fn)

        @functools.wraps(fn)
        def checked(*args, **kwargs):
            try:
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    result = fn(*args, **kwargs)
            except MptrackError:
                raise
            except (*_BREAKDOWNS, SystemError) as exc:
                if isinstance(exc, SystemError) and not isinstance(exc.__cause__, _BREAKDOWNS):
                    raise
                raise _overflow(what, _bound(signature, args, kwargs), exc) from exc
            if not _all_finite(result):
                inputs = _bound(signature, args, kwargs)
                if not any(_has_nan(v) for v in inputs.values()):   # NaN in = missing data, documented
                    raise _overflow(what, inputs, None)
            return result
        return checked
    return wrap


def check_record(name: str, record, fields=("x", "P", "x_pred", "P_pred")) -> None:
    """The array fields of a result record passed in as an argument must be finite arrays with a
    leading time axis (x (T, n), P (T, n, n))."""
    for field in fields:
        value = getattr(record, field, None)
        if value is not None:
            arr = as_array(f"{name}.{field}", _finite_data(_to_array(f"{name}.{field}", value)))
            want = 2 if field.startswith("x") else 3
            if np.ndim(value) != want or not isinstance(value, np.ndarray):
                raise ShapeError(f"{name}.{field}: expected a {want}-D array, got "
                                 f"{type(value).__name__} of shape {arr.shape}")


def _bound(signature, args, kwargs) -> dict:
    bound = signature.bind(*args, **kwargs)
    return {k: v for k, v in bound.arguments.items() if k not in ("args", "kwargs")}


def check_outputs(*inputs, **outputs) -> None:
    """Refuse an output (name=path) that is one of the input files, lies inside an input directory
    (writing it would overwrite the user's data, or add to the dataset), or is the same file as
    another output of the run (the later would overwrite the earlier).

    The same file is found through symbolic links (paths resolved) and, for an output that exists,
    hard links too (:func:`os.path.samefile`).  Inputs that are not paths (None, a table in memory)
    are ignored."""
    sources = [Path(p) for p in inputs if isinstance(p, (str, os.PathLike))]
    named = [(name, Path(path)) for name, path in outputs.items() if path is not None]
    for k, (name, path) in enumerate(named):
        for source in sources:
            if _same_file(path, source):
                raise ParameterError(f"{name}: {path} is an input of this run; writing it would overwrite the input")
            if source.is_dir() and source.resolve() in path.resolve().parents:
                raise ParameterError(f"{name}: {path} is inside the input directory {source}; write it elsewhere "
                                     "(a later read of the directory would take it as input)")
        for other, other_path in named[:k]:
            if _same_file(path, other_path):
                raise ParameterError(f"{name}: {path} is also given as {other}; each output of a run needs a "
                                     "file of its own")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): compare the paths with links resolved
        return a.resolve() == b.resolve()
