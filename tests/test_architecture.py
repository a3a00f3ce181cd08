"""The import rule of the package layout (issue 19; docs/design.md, Layout).

A module of package P (``mptrack/P/...``) may import the private modules (a name starting with "_")
of P itself and the top-level shared infrastructure (``mptrack._validation``, ``mptrack._jit_cache``,
...), and only the public names of any other package.  A top-level module (``mptrack/x.py``) is in
no package: it may import only other top-level modules and public names.  What several packages
share lives in a neutral top-level private module named after its concept, or becomes part of
the owning package's public API.

The source is read with ``ast`` (nothing is imported): every ``import`` and ``from ... import``
anywhere in a module (inside functions too), with relative imports resolved against the module's
own package, and ``from package import _module`` counted as an import of that private module.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"

#: (importing module, imported private module) pairs allowed for now, each with its reason
#: (importing module, imported private module) pairs allowed to break the rule: none (the last one, the
#: continuous UKF kernel's use of nonlinear._step_kernels, went with the shared Kalman core, mptrack._kalman_core)
ALLOWED: set = set()


def _is_module(src: Path, parts: list[str]) -> bool:
    path = src.joinpath(*parts)
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _package(src: Path, parts: list[str]) -> str:
    """The package a module path belongs to ("" for mptrack itself and its top-level modules)."""
    return parts[1] if len(parts) > 1 and (src / parts[0] / parts[1]).is_dir() else ""


def _private(parts: list[str]) -> bool:
    return any(p.startswith("_") and not p.startswith("__") for p in parts[1:])


def imported_modules(src: Path, path: Path):
    """(line, module parts) of every module that ``path`` (a file under ``src``) imports."""
    parts = list(path.relative_to(src).with_suffix("").parts)
    package = parts[:-1]  # the package that relative imports start from (also for an __init__.py)
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name.split(".")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                module = base + (node.module.split(".") if node.module else [])
            else:
                module = node.module.split(".")
            yield node.lineno, module
            for alias in node.names:
                if _is_module(src, module + [alias.name]):
                    yield node.lineno, module + [alias.name]


def violations(src: Path = SRC) -> list[str]:
    """Every import of another package's private module under ``src/mptrack``, as "file:line: module"."""
    found = []
    for path in sorted((src / "mptrack").rglob("*.py")):
        me = list(path.relative_to(src).with_suffix("").parts)
        name = ".".join(p for p in me if p != "__init__")
        for line, module in imported_modules(src, path):
            if module[0] != "mptrack" or not _private(module):
                continue
            target = _package(src, module)
            if target == "" and len(module) == 2:  # top-level shared infrastructure, mptrack._x
                continue
            if target == _package(src, me) or (name, ".".join(module)) in ALLOWED:
                continue
            found.append(f"{path.relative_to(src.parent)}:{line}: {'.'.join(module)}")
    return sorted(set(found))


def test_no_module_imports_another_packages_private_module():
    found = violations()
    assert not found, ("imports of another package's private module (make the name public in that package, "
                       "move shared code to a neutral mptrack._<concept> module, or move it to the package "
                       "that owns the concept):\n" + "\n".join(found))


def test_allowed_exceptions_are_still_needed():
    """An exception that no longer happens is removed from ALLOWED, so the list only shrinks."""
    used = set()
    for path in sorted((SRC / "mptrack").rglob("*.py")):
        me = ".".join(p for p in path.relative_to(SRC).with_suffix("").parts if p != "__init__")
        used |= {(me, ".".join(module)) for _, module in imported_modules(SRC, path)}
    assert ALLOWED <= used, sorted(ALLOWED - used)


def test_nonlinear_does_not_import_continuous():
    """The dependency goes one way: mptrack.continuous uses mptrack.nonlinear's filters and registers its
    model type with them (mptrack._model_families); importing mptrack.nonlinear loads nothing of
    mptrack.continuous (the two packages used to import each other)."""
    code = ("import sys, mptrack.nonlinear; "
            "print(sorted(m for m in sys.modules if m.startswith('mptrack.continuous')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout


@pytest.mark.parametrize("source, bad", [
    ("from ..io._geodesy import geodetic_to_enu\n", True),         # relative, another package
    ("from ..io import _geodesy\n", True),                         # the private module as a name
    ("import mptrack.io._readers\n", True),                        # absolute
    ("def f():\n    from mptrack.io._formats import x\n", True),  # inside a function
    ("from ..io import geodetic_to_enu\n", False),                 # public name
    ("from ._pipeline import track\n", False),                     # own package
    ("from .._validation import as_array\n", False),               # shared infrastructure
])
def test_the_checker_sees_every_form_of_import(tmp_path, source, bad):
    package = tmp_path / "mptrack" / "tracking"
    (tmp_path / "mptrack" / "io").mkdir(parents=True)
    package.mkdir()
    for module in ("mptrack/__init__.py", "mptrack/_validation.py", "mptrack/io/__init__.py",
                   "mptrack/io/_geodesy.py", "mptrack/io/_readers.py", "mptrack/io/_formats.py",
                   "mptrack/tracking/__init__.py", "mptrack/tracking/_pipeline.py"):
        (tmp_path / module).write_text("")
    (package / "_user.py").write_text(source)
    assert bool(violations(tmp_path)) == bad
