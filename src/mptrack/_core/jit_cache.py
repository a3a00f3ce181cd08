"""Where numba keeps mptrack's compiled kernels: a cache directory of the user, never the package.

numba's default puts the machine code of a ``cache=True`` function in a
``__pycache__`` beside its source.  For a package that is the install
directory: read-only in a system or container install (numba then falls back to
a directory of its own, after a failed write per kernel), shared by every user of
one environment, and outside what a user expects a library to write.  Every
kernel module of mptrack imports this module before it compiles anything; it
puts one more locator in front of numba's own, for mptrack's source files only:

    $MPTRACK_CACHE_DIR, else $XDG_CACHE_HOME/mptrack/numba, else ~/.cache/mptrack/numba

with a sub-directory per source directory (numba's own naming: its name and a hash
of its path, so two installs never share entries).  ``NUMBA_CACHE_DIR``, when
the user sets it, keeps its meaning for mptrack too, and an unwritable cache
directory hands over to numba's locators.  numba keys each entry by the source
file's time stamp and size and by the Python version, so an upgrade recompiles.
"""

from __future__ import annotations

import os
from pathlib import Path

from numba.core import caching, config

__all__ = ["cache_root"]

#: mptrack's own directory (this module is in its _core package)
PACKAGE = Path(__file__).resolve().parents[1]


def cache_root() -> Path:
    """The directory under which mptrack's compiled kernels are cached."""
    if os.environ.get("MPTRACK_CACHE_DIR"):
        return Path(os.environ["MPTRACK_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache")
    return Path(base) / "mptrack" / "numba"


class _PackageCacheLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
    """numba cache locator for the functions defined in mptrack's own source files."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = str(cache_root() / self.get_suitable_cache_subpath(py_file))

    def get_cache_path(self) -> str:
        return self._cache_path

    @classmethod
    def from_function(cls, py_func, py_file):
        if config.CACHE_DIR or not os.path.exists(py_file) or not Path(py_file).resolve().is_relative_to(PACKAGE):
            return None
        locator = cls(py_func, py_file)
        try:
            locator.ensure_cache_path()
        except OSError:  # not writable: numba's own locators decide
            return None
        return locator


if _PackageCacheLocator not in caching.CacheImpl._locator_classes:
    caching.CacheImpl._locator_classes.insert(0, _PackageCacheLocator)
