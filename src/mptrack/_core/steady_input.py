"""The ``steady`` argument of the steady-state and FIR filters (single-track and batch): a given
:class:`~mptrack.riccati.SteadyState`, checked against the model, or the one solved for it."""

from __future__ import annotations

import dataclasses

from .validation import frozen
from ..errors import ParameterError
from ..riccati import SteadyState, steady_state

__all__ = ["steady_argument"]

#: The steady states solved for the last few models, by their matrices and the form: solving one
#: (the DARE and its existence checks) costs ~2 ms, a fifth of a batch call of 10^7 updates.
_SOLVED: dict[tuple, SteadyState] = {}
_KEEP = 32


def steady_argument(model, steady, form: str = "kalman") -> SteadyState:
    """``steady`` when it is a SteadyState of the model's dimensions; when None, the model's steady
    state in ``form`` ("kalman": the DARE; "lainiotis": the per-step Lainiotis recursion), solved once
    for equal models (F, H, Q, R) and shared, its arrays read-only."""
    if form not in ("kalman", "lainiotis"):
        raise ParameterError(f"form: expected 'kalman' or 'lainiotis', got {form!r}")
    if steady is not None:
        if not isinstance(steady, SteadyState):
            raise ParameterError(f"steady: expected a SteadyState, got {type(steady).__name__}")
        if steady.A.shape != (model.n, model.n) or steady.B.shape != (model.n, model.m):
            raise ParameterError("steady: its A, B do not match the model's dimensions")
        return steady
    key = (form,) + tuple((M.shape, M.tobytes()) for M in (model.F, model.H, model.Q, model.R))
    solved = _SOLVED.get(key)
    if solved is None:
        if form == "kalman":
            solved = steady_state(model, "dare")
        else:
            solved = steady_state(model, "per-step", form="lainiotis")
        solved = dataclasses.replace(solved, **{f: frozen(getattr(solved, f))
                                                for f in ("K", "P_pred", "P_filt", "A", "B")})
        if len(_SOLVED) >= _KEEP:
            _SOLVED.pop(next(iter(_SOLVED)))
        _SOLVED[key] = solved
    return solved
