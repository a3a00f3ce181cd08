"""Benchmark suites run by ``mptrack bench``.

A suite is ``fn(quick: bool) -> dict`` returning ``{"suite", "title",
"columns", "rows", "notes"}``; modules in this package register theirs with
:func:`register_suite`.  Every suite measures its ratios in the same run
(against a memory-copy baseline and/or peers), never against stored numbers.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Callable

from ..errors import ParameterError, UnknownNameError

__all__ = ["register_suite", "suites", "run_suites"]

_SUITES: dict[str, Callable[[bool], dict]] = {}


def register_suite(name: str):
    """Decorator registering a benchmark suite ``fn(quick) -> dict`` for ``mptrack bench``.

    Parameters
    ----------
    name : str

    Returns
    -------
    callable
        The decorator.
    """
    def deco(fn: Callable[[bool], dict]):
        _SUITES[name] = fn
        return fn
    return deco


def suites() -> dict[str, Callable[[bool], dict]]:
    for mod in pkgutil.iter_modules(__path__):
        if not mod.name.startswith("_"):
            importlib.import_module(f"{__name__}.{mod.name}")
    return dict(_SUITES)


def run_suites(names, quick: bool = False, db: str | None = None) -> list[dict]:
    """Run benchmark suites by name.

    Parameters
    ----------
    names : sequence of str
    quick : bool, optional
        Small sizes (smoke tests).
    db : str, optional
        A PostgreSQL database URL for the serve suite (only with ``names == ["serve"]``): the suite
        then measures the server on that database.

    Returns
    -------
    list of dict
        Each suite's {"suite", "title", "columns", "rows", "notes"}.

    Raises
    ------
    UnknownNameError
        An unknown suite.
    ParameterError
        ``db`` given for other suites than serve.
    """
    reg = suites()
    unknown = [n for n in names if n not in reg]
    if unknown:
        raise UnknownNameError(f"suite: unknown {unknown}; known: {', '.join(reg)}")
    if db is not None and list(names) != ["serve"]:
        raise ParameterError("db: a database is for the serve suite only (--suite serve --db URL)")
    return [reg[n](quick, db=db) if db is not None else reg[n](quick) for n in names]
