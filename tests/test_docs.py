"""Every ```python block in the user guides runs (the docs cannot drift from the code)."""

import re
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"
PAGES = sorted(p for p in DOCS.glob("*.md") if not p.name.startswith("_"))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_code_blocks_run(page, tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S)
    if not blocks:
        pytest.skip("no python blocks")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(page), "exec"), namespace)  # noqa: S102 - our own docs


def _docstring_examples():
    """(name, docstring) of every public object of mptrack whose docstring has doctest examples."""
    import inspect

    from _public import public_objects

    import mptrack

    objects = {**{f"mptrack.{name}": getattr(mptrack, name) for name in mptrack.__all__ if name != "__version__"},
               **public_objects()}
    docs = {name: inspect.getdoc(value) for name, value in objects.items()
            if inspect.isfunction(value) or inspect.isclass(value)}
    return [(name, doc) for name, doc in docs.items() if doc and ">>>" in doc]


@pytest.mark.parametrize("name, doc", _docstring_examples(), ids=lambda v: v if isinstance(v, str) and
                         v.startswith("mptrack.") else "")
def test_docstring_examples_run(name, doc, tmp_path, monkeypatch):
    """The Examples sections of the public docstrings run and print what they say (doctest)."""
    import doctest

    monkeypatch.chdir(tmp_path)
    test = doctest.DocTestParser().get_doctest(doc, {}, name, None, 0)
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS)
    report: list[str] = []
    runner.run(test, out=report.append)
    assert runner.failures == 0, "".join(report)
