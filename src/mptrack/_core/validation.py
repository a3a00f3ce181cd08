"""Input validation at the public boundary.

Each helper takes the argument's *name* so that error messages say which
argument was wrong, what was expected and what was received.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import inspect
import math
import numbers
import os
import re
from pathlib import Path

import numpy as np

from ..errors import (
    DTypeError,
    MptrackError,
    NonFiniteError,
    NotPositiveDefiniteError,
    NotSymmetricError,
    ParameterError,
    ResourceError,
    ShapeError,
    SingularMatrixError,
    UnknownNameError,
)

__all__ = [
    "as_array",
    "check_values",
    "broadcast_shape",
    "as_matrix",
    "as_vector",
    "as_sequence",
    "check_covariance",
    "check_positive",
    "check_int",
    "check_rng",
    "check_bool",
    "lookup",
    "check_frame",
    "point_numbers",
    "check_path",
    "check_outputs",
    "as_real",
    "check_allocation",
    "memory_limit",
    "finite_result",
    "require_finite",
    "check_record",
    "renamed",
    "derived_from",
]


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


#: The name errors give a DataFrame passed instead of a file.
FRAME_LABEL = "<DataFrame>"


def source_label(source):
    """What errors name as the file of ``source`` (a path, or a DataFrame read like a file): its path,
    or FRAME_LABEL for a DataFrame; anything else is a ParameterError naming ``path``."""
    import pandas as pd

    return FRAME_LABEL if isinstance(source, pd.DataFrame) else check_path("path", source)


#: what a reader does with a bad row: raise a DataError naming it, or skip it and count it
ON_ERROR = ("raise", "skip")


def check_on_error(on_error: str) -> str:
    """``on_error`` if it is one of :data:`ON_ERROR`."""
    if on_error not in ON_ERROR:
        raise ParameterError(f"on_error: expected one of {ON_ERROR}, got {on_error!r}")
    return on_error


def check_frame(name: str, value, columns=(), numbers: dict | None = None, *, empty: bool = False):
    """A pandas DataFrame with the ``columns`` and at least one row (any number with ``empty``).
    ``numbers`` maps columns (where present) to the :func:`as_array` options their values must meet
    (``{"t": {}}``: finite numbers; ``{"rss_dbm": dict(allow_nan=True, low=-160, high=0)}``); each is
    checked as the array ``name.column``, so messages start with the argument's name."""
    import pandas as pd

    if not isinstance(value, pd.DataFrame):
        raise ParameterError(f"{name}: expected a pandas DataFrame, got {type(value).__name__}")
    missing = [c for c in columns if c not in value.columns]
    if missing:
        raise ShapeError(f"{name}: expected the column(s) {', '.join(missing)}; it has "
                         f"{', '.join(map(str, value.columns))}")
    if value.empty and not empty:
        raise ShapeError(f"{name}: expected at least one row, got none")
    for col, options in (numbers or {}).items():
        if col in value.columns:
            try:
                data = pd.to_numeric(value[col]).to_numpy(dtype=float, na_value=np.nan)
            except (ValueError, TypeError) as exc:
                raise DTypeError(f"{name}.{col}: expected numbers ({exc})") from None
            as_array(f"{name}.{col}", data, **options)
    return value


#: The text columns of a point table (``mptrack track``'s output); its other columns hold numbers.
POINT_TEXT = ("track_id", "time", "flag", "method", "gap", "is_outlier")


def point_numbers(frame, known=()) -> dict:
    """The :func:`check_frame` ``numbers`` of a point table: t finite, every other column that holds
    numbers (the ``known`` numeric columns, and any column of a numeric dtype) numbers or NaN (what a
    point table leaves out: no NIS at a track's first fix, no velocity, no geographic origin), never
    +-Inf."""
    import pandas as pd

    numeric = [c for c in getattr(frame, "columns", ()) if c not in POINT_TEXT
               and not pd.api.types.is_bool_dtype(frame[c])
               and (c in known or pd.api.types.is_numeric_dtype(frame[c]))]
    return {c: {} if c == "t" else {"allow_nan": True} for c in numeric}


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


# --- output finiteness -------------------------------------------------------------------------

def _finite_data(arr: np.ndarray) -> np.ndarray:
    """The distinct data of a broadcast view (a stride of 0 repeats values: look at one copy)."""
    if arr.size and 0 in arr.strides:
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


def _magnitude(value, smallest: bool = False) -> float:
    """The largest (``smallest``: the smallest non-zero) finite |number| inside an argument (arrays,
    models, results, scalars); 0 when there is none."""
    sizes = [np.abs(a.real if a.dtype.kind == "c" else a) for a in _leaves(value)]
    if smallest:
        sizes = [float(a[np.isfinite(a) & (a > 0)].min()) for a in sizes if (np.isfinite(a) & (a > 0)).any()]
        return min(sizes, default=0.0)
    sizes = [float(a[np.isfinite(a)].max()) for a in sizes if np.isfinite(a).any()]
    return max(sizes, default=0.0)


def require_finite(what: str, value, **inputs) -> None:
    """Raise :class:`NonFiniteError` when ``value`` (an array, a result record) holds NaN or
    infinity although ``inputs`` (name=argument) were finite: an overflow in the computation.
    The message names the input of largest magnitude, the likely cause."""
    if not _all_finite(value):
        raise _overflow(what, inputs, None)


def _by_magnitude(inputs: dict, smallest: bool = False) -> list:
    """[(largest |number|, name), ...] of the inputs, largest first (ties in argument order); with
    ``smallest``, [(smallest non-zero |number|, name), ...] of the inputs that hold one, smallest first."""
    if smallest:
        small = [(_magnitude(v, smallest=True), k) for k, v in inputs.items()]
        return sorted([mk for mk in small if mk[0] > 0], key=lambda mk: mk[0]) or [(0.0, next(iter(inputs)))]
    return sorted(((_magnitude(v), k) for k, v in inputs.items()), key=lambda mk: -mk[0])


#: Inputs all below this magnitude cannot overflow the products of a filter step.
_MODERATE = 1e150
#: An input scale below this, next to moderate ones, leaves nothing to invert in float64 (1e-30 against
#: the unit scale of the others is already below the rounding of their sum).
_NEGLIGIBLE = 1e-100


def _overflow(what: str, inputs: dict, cause) -> NonFiniteError | SingularMatrixError:
    """The error of a computation that broke down (``cause``) or gave NaN/infinity from finite
    ``inputs``: an overflow naming the input of largest magnitude; or, when a matrix turned singular
    although no input is near the float range (a noise variance negligible against the others,
    sigma_r2 = 1e-30 on exact ranges), a SingularMatrixError naming the input of smallest scale.  NaN
    or infinity without an exception from moderate inputs of which one is negligible (below 1e-100)
    is that case too (a division by a rounded-away difference), not an overflow."""
    if isinstance(cause, SystemError) and isinstance(cause.__cause__, _BREAKDOWNS):
        cause = cause.__cause__      # numba wraps an exception raised in compiled code
    sizes = _by_magnitude(inputs)
    moderate = not sizes or sizes[0][0] < _MODERATE
    singular = isinstance(cause, ZeroDivisionError) or (
        isinstance(cause, np.linalg.LinAlgError) and "singular" in str(cause).lower()) or (
        cause is None and moderate and inputs and 0 < _by_magnitude(inputs, smallest=True)[0][0] < _NEGLIGIBLE)
    if singular and moderate:
        small = _by_magnitude(inputs, smallest=True) if inputs else [(0.0, "inputs")]
        first = small[0][1]
        scales = ", ".join(f"|{k}| down to {m:.3g}" for m, k in small if m > 0)
        why = f" ({type(cause).__name__}: {cause})" if cause is not None else " (a NaN or infinity appeared)"
        return _labelled(SingularMatrixError, first,
                         f"a matrix {what} inverts became singular{why}; the inputs "
                         f"hold {scales}: a noise variance negligible against the state's covariance (or an exact "
                         "measurement) leaves nothing to invert; increase the smallest noise variance")
    named = ", ".join(f"|{k}| up to {m:.3g}" for m, k in sizes if m > 0) or "no large values"
    first = sizes[0][1] if sizes else "inputs"
    why = f" ({type(cause).__name__}: {cause})" if cause is not None else ""
    return _labelled(NonFiniteError, first,
                     f"{what} overflowed the float64 range (a NaN or infinity appeared from finite input"
                     f"{why}); the inputs hold {named}; rescale them (e.g. metres -> km) or check the model")


def _labelled(cls, name: str, message: str) -> MptrackError:
    """``cls("name: message")``, remembering the message without the name (see :func:`_caller_named`)."""
    exc = cls(f"{name}: {message}")
    exc._unlabelled = message
    return exc


_BREAKDOWNS = (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError)


def finite_result(what: str):
    """Decorator of the output-finiteness policy (docs/design.md, "Finite answers"):
    the wrapped public function's result (arrays, result records) must be finite; when it is not,
    or when the computation breaks down inside a compiled kernel (a LinAlgError on infinities,
    a division by zero), a :class:`NonFiniteError` names the argument of largest magnitude.
    Arguments are validated by the function itself first (their errors pass through); an mptrack
    error from a quantity derived inside, whose message starts with an internal name, is renamed
    as :func:`derived_from` does.  A NaN result is let through when an argument holds NaN
    (missing data, where the function allows it)."""
    def wrap(fn):
        signature = inspect.signature(fn)
        names = frozenset(signature.parameters)
        if inspect.isgeneratorfunction(fn):     # a generator's steps are results: check each as it comes
            @functools.wraps(fn)
            def steps(*args, **kwargs):
                inputs = _bound(signature, args, kwargs)
                run = fn(*args, **kwargs)
                while True:
                    try:
                        step = _checked(lambda: next(run), inputs, what, names)
                    except StopIteration:
                        return
                    yield step
            return steps

        @functools.wraps(fn)
        def checked(*args, **kwargs):
            return _checked(lambda: fn(*args, **kwargs), _bound(signature, args, kwargs), what, names)
        return checked
    return wrap


def _checked(call, inputs: dict, what: str, names=frozenset()):
    """``call()`` under the output-finiteness policy of :func:`finite_result` (``inputs``: the bound
    arguments; ``names``: every parameter name of the function, given or not)."""
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            result = call()
    except MptrackError as exc:
        named = _caller_named(exc, inputs, names, run=True)
        if named is exc:
            raise
        raise named from exc
    except (*_BREAKDOWNS, SystemError) as exc:
        if isinstance(exc, SystemError) and not isinstance(exc.__cause__, _BREAKDOWNS):
            raise
        raise _overflow(what, inputs, exc) from exc
    if not _all_finite(result) and not any(_has_nan(v) for v in inputs.values()):  # NaN in = missing data
        raise _overflow(what, inputs, None)
    return result


@contextlib.contextmanager
def renamed(**names: str):
    """Errors raised inside that start with an internal argument name start with the caller's instead:
    ``with renamed(stations="sensor"): ...`` turns "stations: ..." into "sensor: ..." (a public
    function that passes its argument on under another name)."""
    try:
        yield
    except MptrackError as exc:
        first = _FIRST_WORD.match(str(exc))
        if not first or first.group(1) not in names:
            raise
        raise _relabelled(exc, names[first.group(1)] + str(exc)[first.end(1):]) from exc


@contextlib.contextmanager
def derived_from(**inputs):
    """Errors about a quantity derived inside from ``inputs`` (name=argument), e.g. the G = [dt^2/2, dt]
    of a model built from dt, start with the input of largest magnitude, the likely cause (as the
    output-finiteness policy names an overflow); errors that already name one of the inputs pass."""
    try:
        yield
    except MptrackError as exc:
        named = _caller_named(exc, inputs)
        if named is exc:
            raise
        raise named from exc


def _caller_named(exc: MptrackError, inputs: dict, names=frozenset(), run: bool = False) -> MptrackError:
    """``exc`` if its message starts with one of ``inputs`` or ``names`` (the function's parameters,
    given or not), or it names a file; else a copy whose message starts with the input of largest
    magnitude, the likely cause.  A singular matrix, and in a filter run (``run``) a covariance that
    lost positive definiteness, come from a scale too small for the others: they name the input of
    smallest scale (see :func:`_overflow`).  An error relabelled before (by a function this one called)
    is relabelled from its own message, so names do not pile up."""
    message = getattr(exc, "_unlabelled", None) or str(exc)
    first = _FIRST_WORD.match(str(exc))
    if (first and (first.group(1) in inputs or first.group(1) in names)) or getattr(exc, "file", None) is not None \
            or getattr(exc, "path", None) is not None or not inputs:
        return exc
    if isinstance(exc, SingularMatrixError) or (run and isinstance(exc, NotPositiveDefiniteError)):
        small = _by_magnitude(inputs, smallest=True)
        scales = ", ".join(f"|{k}| down to {m:.3g}" for m, k in small if m > 0)
        why = "" if "negligible" in message else \
            f" (the inputs hold {scales}: is a noise variance negligible against the others?)"
        return _relabelled(exc, f"{small[0][1]}: {message}{why}", message)
    sizes = _by_magnitude(inputs)
    named = ", ".join(f"|{k}| up to {m:.3g}" for m, k in sizes if m > 0) or "no large values"
    if "(derived from the inputs" in message:
        message = message[:message.index(" (derived from the inputs")]
    return _relabelled(exc, f"{sizes[0][1]}: {message} (derived from the inputs, which hold {named})", message)


_FIRST_WORD = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)")


def _relabelled(exc: MptrackError, message: str, unlabelled: str | None = None) -> MptrackError:
    """A copy of ``exc`` (same class and attributes) with another message; ``unlabelled``: the message
    before a name was put in front (what a later relabelling starts from)."""
    new = copy.copy(exc)
    new.args = (message,) + exc.args[1:]
    if unlabelled is not None:
        new._unlabelled = unlabelled
    return new


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
