"""Every error mptrack raises on bad input, in one place.

All of them derive from :class:`MptrackError` and from the built-in exception a
caller would expect (``ValueError`` or ``TypeError``), so ``except ValueError``
keeps working.  Messages name the argument, what was expected and what was
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
    """A scalar parameter is out of its valid range (negative time step, N < 1, ...)."""
