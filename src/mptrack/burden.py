"""Per-iteration calculation burden (flop counts) of the papers' filters.

Formulas of Assimakis & Adam 2014, Tables 2 and 5 (the same formulas
are Table 2 of Assimakis & Adam 2015), for any state dimension n and measurement
dimension m, and the burden of the 12 implementations of Table 1.

The papers count model B as ``axes`` independent per-axis filters but the
join (averaging) of JKLF/JSSKLF only once (``join="once"``, which reproduces
their Tables 3); ``join="per-axis"`` counts it for every axis, which is what
the per-axis algorithm actually does.
"""

from __future__ import annotations

import math
from fractions import Fraction
from typing import Callable, Literal

from ._core.validation import check_int, check_positive
from .errors import ParameterError, UnknownNameError

__all__ = [
    "FORMULAS",
    "filter_burden",
    "join_burden",
    "implementation_burden",
    "fir_burden",
    "fir_break_even",
    "speedup",
]


def _value(x: Fraction) -> int | float:
    return int(x) if x.denominator == 1 else float(x)


def _kf(n: int, m: int) -> Fraction:
    n, m = Fraction(n), Fraction(m)
    return (4 * n**3 + Fraction(7, 2) * n**2 - Fraction(3, 2) * n + 4 * n**2 * m + n * m
            + 3 * n * m**2 + (16 * m**3 - 3 * m**2 - m) / 6)


def _lf(n: int, m: int) -> Fraction:
    n, m = Fraction(n), Fraction(m)
    return 4 * n * m + (58 * n**3 + 9 * n**2 - 7 * n) / 6


def _ss(n: int, m: int) -> Fraction:
    return Fraction(2 * n * n + 2 * n * m - n)


# name -> (formula text as printed in Table 2, per-iteration burden excluding any join)
FORMULAS: dict[str, tuple[str, Callable[[int, int], Fraction]]] = {
    "KF": ("4n^3 + 3.5n^2 - 1.5n + 4n^2m + nm + 3nm^2 + (16m^3 - 3m^2 - m)/6", _kf),
    "LF": ("4nm + (58n^3 + 9n^2 - 7n)/6", _lf),
    "JKLF": ("n^2 + 3n (join procedure)", lambda n, m: Fraction(n * n + 3 * n)),
    "SSKF": ("2n^2 + 2nm - n", _ss),
    "SSLF": ("2n^2 + 2nm - n", _ss),
    "JSSKLF": ("2n (join procedure)", lambda n, m: Fraction(2 * n)),
}

_JOIN_PARTS = {"JKLF": ("KF", "LF"), "JSSKLF": ("SSKF", "SSLF")}


def _dims(n, m):
    return check_int("n", n, minimum=1), check_int("m", m, minimum=1)


def join_burden(name: str, n: int) -> int:
    """Burden of the join procedure: n^2 + 3n (JKLF) or 2n (JSSKLF).

    Parameters
    ----------
    name : str
        "JKLF" or "JSSKLF".
    n : int

    Returns
    -------
    int

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] N. Assimakis and M. Adam, "Mobile position tracking in three dimensions using Kalman and Lainiotis
           filters", The Open Mathematics Journal, vol. 8, pp. 1–6, 2015 (Bentham Open).
    """
    if not isinstance(name, str) or name not in _JOIN_PARTS:
        raise UnknownNameError(f"name: {name!r} has no join procedure; expected JKLF or JSSKLF")
    return _value(FORMULAS[name][1](check_int("n", n, minimum=1), 1))


def filter_burden(name: str, n: int, m: int) -> int | float:
    """Per-iteration calculation burden of one filter (Assimakis & Adam 2014, Table 2), in exact arithmetic.

    For JKLF/JSSKLF this is both filters plus the join.

    Parameters
    ----------
    name : str
        KF, LF, SSKF, SSLF, JKLF, JSSKLF, FIR (case-insensitive).
    n : int
        State dimension.
    m : int
        Measurement dimension.

    Returns
    -------
    int or float

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] N. Assimakis and M. Adam, "Mobile position tracking in three dimensions using Kalman and Lainiotis
           filters", The Open Mathematics Journal, vol. 8, pp. 1–6, 2015 (Bentham Open).
    """
    n, m = _dims(n, m)
    if not isinstance(name, str) or name not in FORMULAS:
        raise UnknownNameError(f"name: unknown filter {name!r}; known: {', '.join(FORMULAS)}")
    if name in _JOIN_PARTS:
        a, b = _JOIN_PARTS[name]
        return _value(FORMULAS[a][1](n, m) + FORMULAS[b][1](n, m) + FORMULAS[name][1](n, m))
    return _value(FORMULAS[name][1](n, m))


def implementation_burden(filter_name: str, model: Literal["A", "B"], axes: int = 2,
                          join: Literal["once", "per-axis"] = "once") -> int | float:
    """Burden of a Table 1 implementation for the papers' models (2 states, 1 measurement per axis).

    Parameters
    ----------
    filter_name : str
    model : {"A", "B"}
        A: one filter with n = 2 axes, m = axes; B: ``axes`` filters with n = 2, m = 1.
    axes : int, optional
    join : {"once", "per-axis"}, optional
        The join of JKLF/JSSKLF with model B counted once (the papers) or per axis.

    Returns
    -------
    int or float

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] N. Assimakis and M. Adam, "Mobile position tracking in three dimensions using Kalman and Lainiotis
           filters", The Open Mathematics Journal, vol. 8, pp. 1–6, 2015 (Bentham Open).

    Examples
    --------
    >>> from mptrack.burden import implementation_burden
    >>> implementation_burden("KF", "A")
    509
    """
    axes = check_int("axes", axes, minimum=1)
    if not isinstance(filter_name, str) or filter_name not in FORMULAS:
        raise UnknownNameError(f"filter_name: unknown filter {filter_name!r}; known: {', '.join(FORMULAS)}")
    if model == "A":
        return filter_burden(filter_name, 2 * axes, axes)
    if model != "B":
        raise ParameterError(f"model: expected 'A' or 'B', got {model!r}")
    if join not in ("once", "per-axis"):
        raise ParameterError(f"join: expected 'once' or 'per-axis', got {join!r}")
    if filter_name in _JOIN_PARTS and join == "once":
        a, b = _JOIN_PARTS[filter_name]
        return axes * (filter_burden(a, 2, 1) + filter_burden(b, 2, 1)) + join_burden(filter_name, 2)
    return axes * filter_burden(filter_name, 2, 1)


def fir_burden(n: int, m: int, M: int) -> int:
    """Burden of one FIR steady-state output, 2n^2 + 2nm - n + (M - 1) n (Assimakis & Adam 2014, Table 5).

    Parameters
    ----------
    n : int
        State dimension.
    m : int
        Measurement dimension.
    M : int
        FIR order.

    Returns
    -------
    int

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    n, m = _dims(n, m)
    M = check_int("M", M, minimum=1)
    return _value(_ss(n, m) + (M - 1) * n)


def fir_break_even(fir: float, steady: float) -> int:
    """The break-even mu: the nearest integer >= fir / steady (Assimakis & Adam 2014, section 7).

    The FIR filter is cheaper than the recursive one when outputs are needed every mu or more steps.

    Parameters
    ----------
    fir, steady : float
        The burdens of one FIR output and of one steady-state step.

    Returns
    -------
    int

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    fir, steady = check_positive("fir", fir), check_positive("steady", steady)
    return math.ceil(Fraction(fir) / Fraction(steady))


def speedup(slow: float, fast: float) -> float:
    """The papers' speedup of ``fast`` over ``slow``: burden(slow) / burden(fast).

    Parameters
    ----------
    slow, fast : float
        Burdens, > 0.

    Returns
    -------
    float

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] N. Assimakis and M. Adam, "Mobile position tracking in three dimensions using Kalman and Lainiotis
           filters", The Open Mathematics Journal, vol. 8, pp. 1–6, 2015 (Bentham Open).
    """
    slow, fast = check_positive("slow", slow), check_positive("fast", fast)
    if not math.isfinite(slow / fast):
        raise ParameterError(f"fast: the ratio slow / fast = {slow!r} / {fast!r} overflows float64")
    return slow / fast
