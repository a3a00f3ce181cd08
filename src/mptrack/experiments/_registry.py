"""The registry of paper reproductions, and the context a reproduction runs in."""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import pkgutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from .._core.files import read_pickle, write_pickle
from ..errors import UnknownNameError
from ._results import Reproduction

__all__ = ["Experiment", "RunContext", "register", "get_experiment", "experiments"]


class _NullProgress:
    """Progress reporting that does nothing (library use, tests)."""

    @contextlib.contextmanager
    def task(self, description: str, total: int | None = None) -> Iterator[Callable[[int], None]]:
        yield lambda advance=1: None


@dataclass
class RunContext:
    """What a reproduction gets: where to write, its seed, progress reporting, a cache.

    ``cached(name, fn, **params)`` returns ``fn()`` and stores it under
    ``out_dir/.cache``; a rerun with the same name, seed and params loads it
    instead, so an interrupted reproduction resumes without losing finished parts.
    ``quick`` asks for a reduced run (fewer Monte-Carlo runs) for tests.
    """

    out_dir: Path
    seed: int
    quick: bool = False
    resume: bool = True
    progress: Any = field(default_factory=_NullProgress)

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)

    def figure_path(self, filename: str) -> Path:
        return self.out_dir / filename

    def cached(self, name: str, fn: Callable[[], Any], **params) -> Any:
        blob = json.dumps({"seed": self.seed, "quick": self.quick, **params}, sort_keys=True, default=str)
        digest = hashlib.sha256(blob.encode()).hexdigest()[:16]
        path = self.out_dir / ".cache" / f"{name}-{digest}.pkl"
        if self.resume and path.exists():
            return read_pickle(path)
        value = fn()
        write_pickle(path, value)
        return value


@dataclass(frozen=True)
class Experiment:
    key: str
    paper: str
    description: str
    default_seed: int
    run: Callable[[RunContext], Reproduction]


_REGISTRY: dict[str, Experiment] = {}


def register(key: str, *, paper: str, description: str, seed: int = 12345):
    """Decorator registering ``run(ctx) -> Reproduction`` as a reproduction.

    Parameters
    ----------
    key : str
        The reproduction's key (``mptrack reproduce KEY``).
    paper : str
        The paper, by authors and year.
    description : str
    seed : int, optional
        The default seed.

    Returns
    -------
    callable
        The decorator.
    """

    def deco(fn: Callable[[RunContext], Reproduction]):
        if key in _REGISTRY and _REGISTRY[key].run is not fn:
            raise ValueError(f"experiment {key!r} registered twice")
        _REGISTRY[key] = Experiment(key=key, paper=paper, description=description, default_seed=seed, run=fn)
        return fn

    return deco


def _discover() -> None:
    from . import __path__ as pkg_path

    for mod in pkgutil.iter_modules(pkg_path):
        if not mod.name.startswith("_"):
            importlib.import_module(f"{__package__}.{mod.name}")


def experiments() -> dict[str, Experiment]:
    """All registered reproductions, by key (modules in mptrack.experiments are imported)."""
    _discover()
    return dict(sorted(_REGISTRY.items()))


def get_experiment(key: str) -> Experiment:
    """A registered reproduction by key (:func:`experiments`).

    Parameters
    ----------
    key : str

    Returns
    -------
    Experiment

    Raises
    ------
    UnknownNameError
        The name is not registered; the message lists the known names.
    """
    reg = experiments()
    if key not in reg:
        raise UnknownNameError(f"reproduction: unknown key {key!r}; known: {', '.join(reg) or 'none'}")
    return reg[key]


def run_experiment(key: str, out_root: Path, *, seed: int | None = None, quick: bool = False,
                   resume: bool = True, progress: Any = None) -> Reproduction:
    """Run a reproduction into ``out_root/key`` and write its results.json (atomically).

    Parameters
    ----------
    key : str
    out_root : str or path-like
    seed : int, optional
        Overrides the reproduction's default seed.
    quick : bool, optional
        Reduced Monte-Carlo sizes (smoke tests).
    resume : bool, optional
        Reuse the finished parts cached under ``out_root/key/.cache``.
    progress : optional
        A progress reporter (the CLI's).

    Returns
    -------
    Reproduction
    """
    import time

    exp = get_experiment(key)
    ctx = RunContext(out_dir=Path(out_root) / key, seed=exp.default_seed if seed is None else seed,
                     quick=quick, resume=resume, progress=progress or _NullProgress())
    start = time.perf_counter()
    rep = exp.run(ctx)
    rep.elapsed_s = time.perf_counter() - start
    rep.write(ctx.out_dir)
    return rep


def keys() -> Iterable[str]:
    return experiments().keys()
