"""The public objects of mptrack, found on disk, for the tests that check every one of them."""

from __future__ import annotations

import importlib
import pkgutil


def public_objects(skip: tuple = ("cli",)) -> dict:
    """{"mptrack.package.name": object} for every name in the ``__all__`` of every public package or module
    of mptrack (no leading underscore) but those in ``skip`` (the command line's functions are its help
    texts)."""
    import mptrack

    found = {}
    for info in pkgutil.iter_modules(mptrack.__path__):
        if info.name.startswith("_") or info.name in skip:
            continue
        module = importlib.import_module(f"mptrack.{info.name}")
        for name in getattr(module, "__all__", ()):
            found[f"mptrack.{info.name}.{name}"] = getattr(module, name)
    return found
