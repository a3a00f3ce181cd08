"""Membership functions: triangular, trapezoidal and Gaussian, broadcasting over numpy arrays."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._core.finiteness import renamed
from .._core.validation import as_array, as_real, check_allocation, check_int, check_positive
from ..errors import ParameterError

__all__ = ["MembershipFunction", "triangular", "trapezoidal", "gaussian", "uniform_partition"]


def _ramp(x, lo, hi, rising: bool):
    """Linear ramp from 0 at lo to 1 at hi (rising) or 1 at lo to 0 at hi; a step when lo == hi."""
    if hi > lo:
        t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    else:
        t = (x >= lo).astype(float)
    return t if rising else 1.0 - t


def trapezoidal(x, a: float, b: float, c: float, d: float):
    """Trapezoidal membership: 0 below a, rising to 1 on [a, b], 1 on [b, c], falling to 0 on [c, d].

    a = b (or c = d) gives a vertical edge; a = b = -inf (c = d = +inf) a left (right) shoulder, the one
    documented infinity.

    Parameters
    ----------
    x : array_like
        Points of the universe (NaN passes through).
    a, b, c, d : float
        a <= b <= c <= d.

    Returns
    -------
    ndarray
        Memberships in [0, 1], of x's shape.
    """
    x = as_array("x", x, allow_nan=True)
    a, b, c, d = (as_real(k, v, infinite=True) for k, v in (("a", a), ("b", b), ("c", c), ("d", d)))
    if not a <= b <= c <= d:
        raise ParameterError(f"a, b, c, d: expected a <= b <= c <= d, got {a!r}, {b!r}, {c!r}, {d!r}")
    for name, value in (("a", a), ("b", b), ("c", c), ("d", d)):
        shoulder = (a == b == -np.inf) if name in "ab" else (c == d == np.inf)
        if np.isinf(value) and not shoulder:
            raise ParameterError(f"{name}: infinite only for a shoulder (a = b = -inf or c = d = +inf), "
                                 f"got a, b, c, d = {a!r}, {b!r}, {c!r}, {d!r}")
    up = np.ones_like(x) if np.isneginf(b) else _ramp(x, a, b, True)
    down = np.ones_like(x) if np.isposinf(c) else np.where(x <= c, 1.0, _ramp(x, c, d, False))
    return np.minimum(up, down)


def triangular(x, a: float, b: float, c: float):
    """Triangular membership with feet a, c and peak b; a = b or b = c gives a right-angled shoulder.

    Parameters
    ----------
    x : array_like
        Points of the universe (NaN passes through).
    a, b, c : float
        a <= b <= c.

    Returns
    -------
    ndarray
        Memberships in [0, 1], of x's shape.
    """
    b = as_real("b", b, infinite=True)
    if not as_real("a", a, infinite=True) <= b <= as_real("c", c, infinite=True):
        raise ParameterError(f"a, b, c: expected a <= b <= c, got {a!r}, {b!r}, {c!r}")
    with renamed(c="b", d="c"):         # the trapezoid's corners c, d are the triangle's b, c
        return trapezoidal(x, a, b, b, c)


def gaussian(x, mean: float, sigma: float):
    """Gaussian membership exp(-(x - mean)^2 / (2 sigma^2)).

    Parameters
    ----------
    x : array_like
        Points of the universe (NaN passes through).
    mean : float
    sigma : float
        > 0.

    Returns
    -------
    ndarray
        Memberships in [0, 1], of x's shape.
    """
    x = as_array("x", x, allow_nan=True)
    mean, sigma = as_real("mean", mean), check_positive("sigma", sigma)
    with np.errstate(over="ignore", under="ignore"):  # (x - mean) / sigma = inf gives exp(-inf) = 0
        return np.exp(-0.5 * ((x - mean) / sigma) ** 2)


_KINDS = {"triangular": (triangular, 3), "trapezoidal": (trapezoidal, 4), "gaussian": (gaussian, 2)}


@dataclass(frozen=True)
class MembershipFunction:
    """A named fuzzy set: ``kind`` in {"triangular", "trapezoidal", "gaussian"} with its parameters."""

    kind: str
    params: tuple[float, ...]
    label: str = ""

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ParameterError(f"kind: expected one of {tuple(_KINDS)}, got {self.kind!r}")
        want = _KINDS[self.kind][1]
        if isinstance(self.params, (str, bytes)) or not np.iterable(self.params) or len(self.params) != want:
            raise ParameterError(f"params: a {self.kind} membership function takes {want} parameters, "
                                 f"got {self.params!r}")
        p = tuple(as_real("params", v, infinite=True) for v in self.params)
        object.__setattr__(self, "params", p)
        if self.kind == "gaussian":
            if not (np.isfinite(p[0]) and p[1] > 0):
                raise ParameterError(f"params: gaussian needs a finite mean and sigma > 0, got {p}")
        elif any(np.isnan(p)) or list(p) != sorted(p):
            raise ParameterError(f"params: {self.kind} corners must be non-decreasing, got {p}")

    def __call__(self, x):
        return _KINDS[self.kind][0](x, *self.params)


def uniform_partition(lo: float, hi: float, count: int, *, labels=None, kind: str = "triangular"):
    """Fuzzy sets evenly covering [lo, hi] (a Ruspini partition: memberships sum to 1).

    Triangular: peaks at lo + i (hi - lo)/(count - 1), feet at the neighbouring peaks, the first and last
    sets shoulders (1 outside the universe).  Gaussian: the same centres, sigma = spacing / 2
    (memberships then sum to 1 only approximately).

    Parameters
    ----------
    lo, hi : float
        The universe, lo < hi.
    count : int
        Number of sets, >= 2.
    labels : sequence of str, optional
    kind : {"triangular", "gaussian"}, optional

    Returns
    -------
    list of MembershipFunction

    Examples
    --------
    >>> from mptrack.fuzzy import uniform_partition
    >>> sets = uniform_partition(0.0, 1.5, 5)
    >>> [round(float(s(0.375)), 2) for s in sets]
    [0.0, 1.0, 0.0, 0.0, 0.0]
    """
    lo, hi = as_real("lo", lo), as_real("hi", hi)
    count = check_int("count", count, minimum=2)
    check_allocation("count", count, 1024.0 * count)     # one MembershipFunction (about 1 KiB) per set
    if not hi > lo:
        raise ParameterError(f"hi: expected hi > lo, got lo, hi = {lo!r}, {hi!r}")
    if not np.isfinite(hi - lo):
        raise ParameterError(f"hi: the universe [lo, hi] = [{lo!r}, {hi!r}] is wider than the float64 range")
    if kind not in ("triangular", "gaussian"):
        raise ParameterError(f"kind: expected 'triangular' or 'gaussian', got {kind!r}")
    if labels is not None and (isinstance(labels, (str, bytes)) or not np.iterable(labels)):
        raise ParameterError(f"labels: expected {count} labels, got {labels!r}")
    labels = list(labels) if labels is not None else [f"A{i}" for i in range(count)]
    if len(labels) != count:
        raise ParameterError(f"labels: expected {count} labels, got {len(labels)}")
    centres = np.linspace(lo, hi, count)
    step = centres[1] - centres[0]
    out = []
    for i, (c, lab) in enumerate(zip(centres, labels)):
        if kind == "gaussian":
            out.append(MembershipFunction("gaussian", (c, step / 2), lab))
            continue
        left = -np.inf if i == 0 else centres[i - 1]
        right = np.inf if i == count - 1 else centres[i + 1]
        if kind == "triangular":
            if i == 0:
                out.append(MembershipFunction("trapezoidal", (-np.inf, -np.inf, c, right), lab))
            elif i == count - 1:
                out.append(MembershipFunction("trapezoidal", (left, c, np.inf, np.inf), lab))
            else:
                out.append(MembershipFunction("triangular", (left, c, right), lab))
        else:
            raise ParameterError(f"kind: expected 'triangular' or 'gaussian', got {kind!r}")
    return tuple(out)
