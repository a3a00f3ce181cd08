"""Profiling of the FEM grid filter: the time of a run split into its parts, by timing the filter's own
functions in place (so it follows the code it measures; the benchmark suite reports it)."""

from __future__ import annotations

import time
import timeit
from unittest import mock

import numpy as np

from .._core.validation import check_int
from . import _fem, _fem_grid, _fem_kernels, _fem_schemes
from ._fem import fem_filter
from ._model import ContinuousDiscreteModel

__all__ = ["fem_profile"]

#: most runs of the filter a profile takes the best of
MAX_REPEATS = 100


def _best_time(fn, repeats: int) -> float:
    return min(timeit.repeat(fn, number=1, repeat=repeats))


def fem_profile(model: ContinuousDiscreteModel, z, x0, P0, *, grid: tuple[int, int] = (20, 20),
                repeats: int = 1) -> dict:
    """Where the time of the default FEM grid filter goes, per measurement step.

    The run with the smallest total of ``repeats`` gives the total and the time in the predictions and the
    updates; the prediction's time is split in proportion to the cost of its pieces (grid placement,
    carrying the density, diffusion, factorisations), each timed alone on the run's own inputs.
    ``mptrack bench --suite nonlinear`` reports it.

    Parameters
    ----------
    model : ContinuousDiscreteModel
        The SDE model observed at discrete times.
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped.
    x0 : array_like, shape (n,)
        The prior mean at time 0.
    P0 : array_like, shape (n, n)
        The prior covariance at time 0.
    grid : tuple of int, optional
        (n1, n2) elements per axis.
    repeats : int, optional
        Runs, 1 to 100.

    Returns
    -------
    dict
        {part: seconds per measurement step}.
    """
    repeats = check_int("repeats", repeats, minimum=1, maximum=MAX_REPEATS)

    def timed(fn, log, record=None):
        def wrapper(*args):
            t = time.perf_counter()
            out = fn(*args)
            log.append(time.perf_counter() - t)
            if record is not None:
                record.append(args)
            return out
        return wrapper

    best = None
    for _ in range(repeats):
        updates, predictions, inputs = [], [], []
        with mock.patch.object(_fem_schemes._Characteristics, "predict",
                               timed(_fem_schemes._Characteristics.predict, predictions, inputs)), \
                mock.patch.object(_fem, "_update", timed(_fem._update, updates)):
            t = time.perf_counter()
            fem_filter(model, z, x0, P0, grid=grid)
            total = time.perf_counter() - t
        if best is None or total < best[0]:
            best = (total, sum(predictions), sum(updates), inputs)
    total, predict, update, inputs = best
    scheme = inputs[0][0]
    transports, diffusions = [], []
    with mock.patch.object(_fem_schemes, "transport_split", timed(_fem_schemes.transport_split, [], transports)), \
            mock.patch.object(_fem_schemes, "diffuse_kept", timed(_fem_schemes.diffuse_kept, [], diffusions)):
        for s, g, p in inputs:
            s.predict_steps(g, p)
    placed = [_fem_kernels.place_grid(p, lo, hi, d, grid_, place, flow) for p, lo, hi, _, d, grid_, place, flow, _ in
              transports]
    pieces = {
        "placement": sum(_best_time(lambda a=a: _fem_kernels.place_grid(a[0], a[1], a[2], *a[4:8]), repeats) for a in transports),
        "carry": sum(_best_time(lambda a=a, new=new: _fem_kernels.carry(*a[:3], new[1], new[2], a[4], a[5], *a[7:]), repeats)
                     for a, new in zip(transports, placed)),
        "diffusion": sum(_best_time(lambda a=a: _fem_schemes.diffuse_kept(*a), repeats) for a in diffusions),
        "factorisations": scheme.factorisations * _best_time(
            lambda: _fem_schemes._band_cholesky(_fem_grid._topology(*grid), _fem_grid._topology(*grid)["Me"], np.float32),
            repeats)}
    share = predict / sum(pieces.values())
    steps = z.shape[0]
    parts = {"grid placement (moments, sigma points, box)": pieces["placement"] * share,
             f"transport ({len(transports) / steps:.0f} per step: node flow, quadrature, deposit, mass solve)":
                 pieces["carry"] * share,
             f"diffusion ({len(diffusions) / steps:.0f} per step: SDIRK2 on kept factorisations)":
                 pieces["diffusion"] * share,
             f"diffusion factorisations ({scheme.factorisations / steps:.2f} per step)":
                 pieces["factorisations"] * share,
             "update (likelihood, search for separate modes, Bayes' rule)": update,
             "the rest (merging mixture parts, moments, step records, Python)": total - predict - update}
    return {label: t / steps for label, t in parts.items()}
