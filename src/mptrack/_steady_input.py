"""The ``steady`` argument of the steady-state and FIR filters (single-track and batch): a given
:class:`~mptrack.riccati.SteadyState`, checked against the model, or the one solved for it."""

from __future__ import annotations

from .errors import ParameterError
from .riccati import SteadyState, steady_state

__all__ = ["steady_argument"]


def steady_argument(model, steady, form: str = "kalman") -> SteadyState:
    """``steady`` when it is a SteadyState of the model's dimensions; when None, the model's steady
    state in ``form`` ("kalman": the DARE; "lainiotis": the per-step Lainiotis recursion)."""
    if form not in ("kalman", "lainiotis"):
        raise ParameterError(f"form: expected 'kalman' or 'lainiotis', got {form!r}")
    if steady is not None:
        if not isinstance(steady, SteadyState):
            raise ParameterError(f"steady: expected a SteadyState, got {type(steady).__name__}")
        if steady.A.shape != (model.n, model.n) or steady.B.shape != (model.n, model.m):
            raise ParameterError("steady: its A, B do not match the model's dimensions")
        return steady
    if form == "kalman":
        return steady_state(model, "dare")
    return steady_state(model, "per-step", form="lainiotis")
