"""Names that moved to another package, still served from the old one for one release.

A package lists its moved names and sets ``__getattr__ = moved_names(__name__, {name: new package})``
(PEP 562): ``from old import name`` then returns the object of the new package, with a
DeprecationWarning that names the new place.
"""

from __future__ import annotations

import importlib
import warnings

__all__ = ["moved_names"]


def moved_names(package: str, moved: dict[str, str]):
    """The module ``__getattr__`` of ``package`` serving each moved name from its new package."""

    def __getattr__(name: str):
        if name not in moved:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        new = moved[name]
        warnings.warn(f"{package}.{name} moved to {new}.{name}; import it from {new} (the old path will be "
                      f"removed in the next release)", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(new), name)

    return __getattr__
