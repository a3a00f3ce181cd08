"""Names that moved to another package or were renamed, still served from the old place for one release.

A package lists its moved names and sets ``__getattr__ = moved_names(__name__, {old name: new place})``
(PEP 562), where the new place is the new package (same name) or ``(package, new name)`` (renamed):
``from old import name`` then returns the object of the new place, with a DeprecationWarning that names
it.
"""

from __future__ import annotations

import importlib
import warnings

__all__ = ["moved_names"]


def moved_names(package: str, moved: dict[str, str | tuple[str, str]]):
    """The module ``__getattr__`` of ``package`` serving each moved or renamed name from its new place."""

    def __getattr__(name: str):
        if name not in moved:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        new, new_name = (moved[name], name) if isinstance(moved[name], str) else moved[name]
        verb = "moved to" if new_name == name else "is now"
        warnings.warn(f"{package}.{name} {verb} {new}.{new_name}; import it from there (the old name will be removed "
                      f"in the next release)", DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(new), new_name)

    return __getattr__
