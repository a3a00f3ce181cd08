"""Join filters (JKLF, JSSKLF; Assimakis & Adam 2014, eqs. 8, 16) and per-axis running of model B."""

from __future__ import annotations

from typing import Callable

import numpy as np

from .._core.validation import (
    _to_array,
    as_sequence,
    as_vector,
    check_covariance,
    check_int,
    check_record,
)
from ..errors import ParameterError, ShapeError
from ..models import LinearGaussianModel, require_model
from ..result import FilterResult, mask_missing

__all__ = ["join_results", "per_axis"]


def join_results(a: FilterResult, b: FilterResult, method: str) -> FilterResult:
    """The papers' join of two filters' estimates: x = (x_a + x_b)/2, P = (P_a + P_b)/2.

    Parameters
    ----------
    a, b : FilterResult
        Two filters' results on the same measurements.
    method : str
        The joined result's method name (e.g. "JKLF").

    Returns
    -------
    FilterResult

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    for name, result in (("a", a), ("b", b)):
        if not isinstance(result, FilterResult):
            raise ParameterError(f"{name}: expected a FilterResult, got {type(result).__name__}")
        check_record(name, result, fields=("x", "P"))
    if b.x.shape != a.x.shape or b.P.shape != a.P.shape:
        raise ShapeError(f"b: expected x {a.x.shape} and P {a.P.shape} as a's, got {b.x.shape} and {b.P.shape}")
    if not isinstance(method, str):
        raise ParameterError(f"method: expected a name (str), got {method!r}")
    return FilterResult(x=0.5 * (a.x + b.x), P=0.5 * (a.P + b.P), method=method)


def per_axis(run: Callable[..., FilterResult], axis_model: LinearGaussianModel, z, x0=None, P0=None,
             **kwargs) -> FilterResult:
    """Run a filter on each axis of an axis-by-axis model and join the states (Assimakis & Adam 2014,
    eqs. 17-18).

    Parameters
    ----------
    run : callable
        ``run(axis_model, z_axis, x0_axis, P0_axis, **kwargs) -> FilterResult``.
    axis_model : LinearGaussianModel
        The model of one axis.
    z : array_like, shape (T, axes * m_axis)
        Measurements axis by axis (columns [z_x, z_y, ...]).
    x0 : array_like, shape (axes * n_axis,), optional
        The prior, axis by axis.
    P0 : array_like, optional
        The prior covariance, block-diagonal (off-diagonal blocks zero to 1e-12 relative: the axes are
        independent).
    **kwargs
        Passed to ``run``.

    Returns
    -------
    FilterResult
        The joint state [x_axis0, x_axis1, ...] with a block-diagonal covariance.

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    """
    require_model(axis_model, "axis_model")
    if not callable(run):
        raise ParameterError(f"run: expected a filter function, got {run!r}")
    na, ma = axis_model.n, axis_model.m
    z = _to_array("z", z)
    if z.ndim != 2 or z.shape[1] % ma:
        raise ShapeError(f"z: expected shape (T, axes * {ma}), got shape {z.shape}")
    axes = check_int("axes", z.shape[1] // ma, minimum=1)
    z = as_sequence("z", z, axes * ma, allow_nan=True)
    n = axes * na
    x0 = np.zeros(n) if x0 is None else as_vector("x0", x0, n)
    P0 = np.zeros((n, n)) if P0 is None else check_covariance("P0", P0, n)
    blocks = [slice(i * na, (i + 1) * na) for i in range(axes)]
    off = P0.copy()
    for s in blocks:
        off[s, s] = 0.0
    worst = float(np.max(np.abs(off)))
    if worst > 1e-12 * max(float(np.max(np.abs(P0))), np.finfo(float).tiny):
        raise ParameterError("P0: model B runs the axes independently; P0 must be block-diagonal "
                         f"(largest off-block entry {worst:.3g})")
    parts = [run(axis_model, z[:, i * ma:(i + 1) * ma], x0[s], P0[s, s], **kwargs)
             for i, s in enumerate(blocks)]
    x = np.concatenate([p.x for p in parts], axis=1)
    T = x.shape[0]
    P = np.zeros((T, n, n))
    for s, p in zip(blocks, parts):
        P[:, s, s] = p.P
    def _cat(attr):
        vals = [getattr(p, attr) for p in parts]
        return None if any(v is None for v in vals) else vals
    x_pred = _cat("x_pred")
    P_pred = None
    if x_pred is not None:
        x_pred = np.concatenate(x_pred, axis=1)
        P_pred = np.zeros((T, n, n))
        for s, p in zip(blocks, parts):
            P_pred[:, s, s] = p.P_pred
    lls = _cat("loglik")
    loglik = None if lls is None else float(sum(lls))
    innovation = _cat("innovation")
    S = None
    if innovation is not None:
        innovation = np.concatenate(innovation, axis=1)
        S = np.zeros((T, axes * ma, axes * ma))
        for i, p in enumerate(parts):
            S[:, i * ma:(i + 1) * ma, i * ma:(i + 1) * ma] = p.S
        mask_missing(innovation, S)
    return FilterResult(x=x, P=P, x_pred=x_pred, P_pred=P_pred, loglik=loglik, method=parts[0].method,
                        innovation=innovation, S=S)
