"""The layout and import rules of the package (issues 19 and 34; docs/design.md, Layout).

* A module of package P (``mptrack/P/...``) may import the private modules (a name starting with
  "_") of P itself and the shared private layer ``mptrack._core`` (the numerical cores and the
  shared infrastructure: ``mptrack._core.kalman``, ``mptrack._core.validation``, ...), and only the
  public names of any other package.  A top-level module (``mptrack/x.py``) is in no package: it may
  import only other top-level modules, ``mptrack._core`` and public names.  What several packages
  share lives in ``mptrack._core`` under its concept's name, or becomes part of the owning package's
  public API.
* The root holds only public modules and ``_core``.
* No import circle anywhere: the graph of module imports (inside functions too; a package's
  ``__init__`` imports its modules) has no cycle.
* ``mptrack.io`` holds formats: it imports nothing of ``batch``, ``tracking``, ``runs``, ``report``
  or ``cli``.

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

#: (importing module, imported private module) pairs allowed to break the rule: none (the last one, the
#: continuous UKF kernel's use of nonlinear._step_kernels, went with the shared Kalman core, mptrack._core.kalman)
ALLOWED: set = set()
#: The shared private layer that every module may import.
CORE = "_core"


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
            if target == CORE:  # the shared private layer, mptrack._core.x
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
    model type with them (mptrack._core.model_families); importing mptrack.nonlinear loads nothing of
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
    ("from .._core.validation import as_array\n", False),         # the shared private layer
    ("from .._core import validation\n", False),                  # the same, as a module name
])
def test_the_checker_sees_every_form_of_import(tmp_path, source, bad):
    package = tmp_path / "mptrack" / "tracking"
    (tmp_path / "mptrack" / "io").mkdir(parents=True)
    (tmp_path / "mptrack" / "_core").mkdir()
    package.mkdir()
    for module in ("mptrack/__init__.py", "mptrack/_core/__init__.py", "mptrack/_core/validation.py",
                   "mptrack/io/__init__.py",
                   "mptrack/io/_geodesy.py", "mptrack/io/_readers.py", "mptrack/io/_formats.py",
                   "mptrack/tracking/__init__.py", "mptrack/tracking/_pipeline.py"):
        (tmp_path / module).write_text("")
    (package / "_user.py").write_text(source)
    assert bool(violations(tmp_path)) == bad


def _modules(src: Path) -> dict[str, Path]:
    """Every module under ``src/mptrack`` by dotted name (a package by its ``__init__``)."""
    return {".".join(p for p in path.relative_to(src).with_suffix("").parts if p != "__init__"): path
            for path in sorted((src / "mptrack").rglob("*.py"))}


def import_graph(src: Path = SRC) -> dict[str, set[str]]:
    """module -> the mptrack modules it imports (anywhere in it).  An import of a name from a package
    is an import of the package's ``__init__``; a module's own parent packages, which Python imports
    before the module in any case, are not counted."""
    modules = _modules(src)
    graph = {}
    for name, path in modules.items():
        edges = set()
        for _, module in imported_modules(src, path):
            found = next((".".join(module[:k]) for k in range(len(module), 0, -1)
                          if ".".join(module[:k]) in modules), None)
            if found is not None and found != name and not name.startswith(found + "."):
                edges.add(found)
        graph[name] = edges
    return graph


def import_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of ``graph``: its strongly connected components of more than one module
    (Tarjan's algorithm, iterative), each with one circle through it spelled out."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(_circle(graph, set(component)))
    return found


def _circle(graph: dict[str, set[str]], component: set[str]) -> list[str]:
    """One circle through the first module of ``component`` (breadth-first back to it)."""
    start = min(component)
    paths = {start: [start]}
    queue = [start]
    while queue:
        v = queue.pop(0)
        for w in sorted(graph[v] & component):
            if w == start:
                return paths[v] + [start]
            if w not in paths:
                paths[w] = paths[v] + [w]
                queue.append(w)
    return sorted(component)


def test_no_import_circle():
    circles = import_circles(import_graph())
    assert not circles, "import circles (move what both sides need to the module that owns it, or to " \
                        "mptrack._core):\n" + "\n".join(" -> ".join(c) for c in circles)


def test_the_circle_finder_finds_a_circle(tmp_path):
    """The check can fail: a -> b -> c -> a inside a package, and one through a package's __init__."""
    package = tmp_path / "mptrack" / "io"
    package.mkdir(parents=True)
    (tmp_path / "mptrack" / "__init__.py").write_text("")
    (package / "__init__.py").write_text("from ._a import x\n")
    (package / "_a.py").write_text("def f():\n    from ._b import y\n")
    (package / "_b.py").write_text("from ._c import z\n")
    (package / "_c.py").write_text("from . import _a\n")
    (package / "_d.py").write_text("from ..io import x\n")   # a module importing its own package: no circle
    assert import_circles(import_graph(tmp_path)) == [["mptrack.io._a", "mptrack.io._b", "mptrack.io._c",
                                                       "mptrack.io._a"]]
    other = tmp_path / "mptrack" / "runs"
    other.mkdir()
    (other / "__init__.py").write_text("from ._e import e\n")
    (other / "_e.py").write_text("from ..io import x\n")
    (package / "_c.py").write_text("from ..runs import e\n")
    assert import_circles(import_graph(tmp_path)) == [["mptrack.io", "mptrack.io._a", "mptrack.io._b",
                                                       "mptrack.io._c", "mptrack.runs", "mptrack.runs._e",
                                                       "mptrack.io"]]


#: What mptrack.io (formats, schemas, geodesy) must not import: the packages that use it.
IO_MUST_NOT_IMPORT = ("batch", "tracking", "runs", "report", "cli", "experiments", "bench")


def test_io_imports_nothing_of_the_packages_that_use_it():
    found = [f"{path.relative_to(SRC.parent)}:{line}: {'.'.join(module)}"
             for path in sorted((SRC / "mptrack" / "io").rglob("*.py"))
             for line, module in imported_modules(SRC, path)
             if module[0] == "mptrack" and len(module) > 1 and module[1] in IO_MUST_NOT_IMPORT]
    assert not found, "mptrack.io imports a package that uses it:\n" + "\n".join(found)


#: The only private entries of src/mptrack: the shared private layer (and Python's own dunder modules).
ROOT_PRIVATE = {"_core"}


def test_the_root_holds_only_public_modules_and_core():
    root = SRC / "mptrack"
    private = sorted(p.name for p in root.iterdir()
                     if p.name.startswith("_") and not p.name.startswith("__")
                     and (p.suffix == ".py" or (p / "__init__.py").is_file())
                     and p.with_suffix("").name not in ROOT_PRIVATE)
    assert not private, (f"private modules at the root of mptrack: {private}; a numerical core or shared "
                         "infrastructure goes into mptrack/_core/, a module with one user package into it")
    assert (root / "_core" / "__init__.py").is_file()


def _public_functions() -> dict:
    """{"mptrack.package.name": function} of every public function with parameters (and mptrack.track,
    mptrack.simulate)."""
    import inspect

    import mptrack
    from _public import public_objects

    found = {f"mptrack.{name}": getattr(mptrack, name) for name in ("track", "simulate")}
    found.update({name: value for name, value in public_objects().items()
                  if inspect.isfunction(value) and inspect.signature(value).parameters})
    return found


def _has_parameters(function) -> bool:
    import inspect

    return "\nParameters\n----------\n" in "\n" + (inspect.getdoc(function) or "")


def test_every_public_function_has_a_numpydoc_parameters_section():
    """The public docstrings are numpydoc (issue 34, item 7): at least a Parameters section (the
    Returns, Raises, References and Examples sections follow the same form)."""
    missing = sorted(name for name, fn in _public_functions().items() if not _has_parameters(fn))
    assert not missing, "public functions without a numpydoc Parameters section:\n" + "\n".join(missing)
