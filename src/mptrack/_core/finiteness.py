"""Finite answers or clear errors: the finiteness of results (:func:`require_finite`,
:func:`finite_result`) and errors relabelled with the names the caller passed (:func:`renamed`,
:func:`derived_from`).  A non-finite result from finite input becomes a NonFiniteError naming the input
of largest magnitude; a singular matrix among moderate inputs, a SingularMatrixError naming the
smallest.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import inspect
import numbers
import re

import numpy as np

from ..errors import MptrackError, NonFiniteError, NotPositiveDefiniteError, SingularMatrixError

__all__ = ["require_finite", "finite_result", "renamed", "derived_from"]

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
    """Decorator of the output-finiteness policy (docs/design.md, Contracts; docs/decisions/2026-11-25-finite-answers.md):
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


def _bound(signature, args, kwargs) -> dict:
    bound = signature.bind(*args, **kwargs)
    return {k: v for k, v in bound.arguments.items() if k not in ("args", "kwargs")}
