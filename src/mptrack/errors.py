"""Every error mptrack raises on bad input, in one place.

All of them derive from :class:`MptrackError` and from the built-in exception a
caller would expect (``ValueError`` or ``TypeError``; ``OSError`` for an output
that cannot be written), so ``except ValueError`` keeps working.  Messages name the argument, what was expected and what was
received.
"""

from __future__ import annotations

__all__ = [
    "MptrackError",
    "ShapeError",
    "DTypeError",
    "NonFiniteError",
    "NotSymmetricError",
    "NotPositiveDefiniteError",
    "NotDetectableError",
    "NotStabilisableError",
    "ConvergenceError",
    "SingularMatrixError",
    "UnknownNameError",
    "ParameterError",
    "DataError",
    "OutputError",
    "ResourceError",
    "RequestError",
]


class MptrackError(Exception):
    """Base class of every mptrack error."""


class ShapeError(MptrackError, ValueError):
    """An array argument has the wrong number of dimensions or wrong sizes."""


class DTypeError(MptrackError, TypeError):
    """An array argument has a dtype that cannot be used (complex, object, ...)."""


class NonFiniteError(MptrackError, ValueError):
    """An argument contains NaN or infinity where finite values are required."""


class NotSymmetricError(MptrackError, ValueError):
    """A covariance matrix is not symmetric."""


class NotPositiveDefiniteError(MptrackError, ValueError):
    """A covariance matrix is not positive (semi-)definite as required."""


class NotDetectableError(MptrackError, ValueError):
    """The pair (F, H) is not detectable: no steady-state filter exists."""


class NotStabilisableError(MptrackError, ValueError):
    """The pair (F, Q^{1/2}) is not stabilisable: the steady state is not stabilising."""


class ConvergenceError(MptrackError, ValueError):
    """An iterative solver did not converge within its iteration budget."""


class SingularMatrixError(MptrackError, ValueError):
    """A matrix that has to be inverted is singular (or numerically so)."""


class UnknownNameError(MptrackError, KeyError, ValueError):
    """A name looked up in a registry (filter, experiment, ...) does not exist.

    A KeyError (it is a failed look-up) and a ValueError (it is a bad argument
    value), so both ``except KeyError`` and ``except ValueError`` catch it."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


class ParameterError(MptrackError, ValueError):
    """A parameter, or a value of an array argument, is out of its valid range (negative time
    step, N < 1, a latitude outside [-90, 90] degrees, ...)."""


class DataError(MptrackError, ValueError):
    """A record in an input file is invalid: names the file, the row and the column.

    ``row`` is the 1-based number of the data record (the header line of a CSV
    file is not counted; for GPX it is the track point's number), or None when
    the problem concerns the whole file (a missing column, an unreadable file).
    """

    def __init__(self, message: str, *, file=None, row: int | None = None, column: str | None = None):
        self.file, self.row, self.column, self.reason = file, row, column, message
        where = [str(file)] if file is not None else []
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column {column!r}")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)


class OutputError(MptrackError, OSError):
    """An output cannot be written: its directory is read-only, the disk is full, the path is a
    directory, or another run is writing it (its lock is held).

    ``path`` is the output concerned; the message names it and the cause ("No space left on
    device", "Permission denied", the other run's process id).  An OSError, so ``except OSError``
    catches it; ``errno`` is the operating system's error number when there is one."""

    def __init__(self, message: str, *, path=None, errno: int | None = None):
        super().__init__(message)
        self.path = path
        self.errno = errno


class ResourceError(MptrackError, ValueError):
    """An argument asks for more memory (or time) than the run may use: the message names the
    argument, the bytes needed and the limit (``MPTRACK_MAX_BYTES``, default half the machine's
    physical memory)."""


class RequestError(MptrackError, ValueError):
    """A request to the live server (``mptrack serve``) cannot be accepted: a field of a fix is missing
    or out of range, the body is not what its content type says, it is too large, the device is not
    known or is sending too fast.

    ``status`` is the HTTP status the server answers with (400, 401, 404, 413, 415, 422, 429),
    ``code`` a short machine-readable reason ("invalid_field", "missing_field", ...) and ``field``
    the name of the offending field as the client sent it (None when the request as a whole is
    refused)."""

    def __init__(self, message: str, *, status: int = 400, code: str = "invalid_field", field: str | None = None):
        super().__init__(f"{field}: {message}" if field else message)
        self.status, self.code, self.field, self.reason = status, code, field, message
