"""Validity ranges of the empirical propagation models, and what to do outside them."""

from __future__ import annotations

import warnings


from .._core.validation import as_array
from ..errors import ParameterError

__all__ = ["ValidityWarning", "check_range", "check_policy", "POLICIES"]

POLICIES = ("raise", "warn", "ignore")


class ValidityWarning(UserWarning):
    """A propagation model was evaluated outside the parameter range it was fitted on."""


def check_policy(on_invalid: str) -> str:
    if on_invalid not in POLICIES:
        raise ParameterError(f"on_invalid: expected one of {POLICIES}, got {on_invalid!r}")
    return on_invalid


def check_range(model: str, name: str, value, lo: float, hi: float, unit: str, on_invalid: str) -> None:
    """Raise ParameterError, warn with ValidityWarning or do nothing when ``value`` leaves [lo, hi]."""
    if on_invalid == "ignore":
        return
    arr = as_array(name, value)
    bad = (arr < lo) | (arr > hi)
    if not bad.any():
        return
    worst = arr[bad].flat[0]
    msg = (f"{name}: {model} is valid for {lo:g} <= {name} <= {hi:g} {unit}, got {worst:g} {unit}"
           f" ({int(bad.sum())} value(s) outside); pass on_invalid='warn' or 'ignore' to extrapolate")
    if on_invalid == "raise":
        raise ParameterError(msg)
    warnings.warn(msg, ValidityWarning, stacklevel=3)
