"""The links of a reproduction's report to docs/errata.md: every erratum key a reproduction can cite
(the ``explained_by`` keys of results.json) is an anchor of the real docs/errata.md, and the page links
each explained cell to that anchor, whatever the CLI does to the text before the page is built."""

from __future__ import annotations

import importlib
import pkgutil
import re
from pathlib import Path

import mptrack.experiments as experiments_pkg
from mptrack.experiments import experiments
from mptrack.report import write_reproduction_report

ROOT = Path(__file__).resolve().parents[1]
ERRATA = ROOT / "docs" / "errata.md"
SOURCE = ROOT / "src" / "mptrack" / "experiments"


def anchors(text: str) -> set[str]:
    """The explicit anchors of a Markdown page: ``<a id="KEY"></a>`` and ``{#KEY}``."""
    return set(re.findall(r"<a id=\"([^\"]+)\"></a>", text)) | set(re.findall(r"\{#([\w-]+)\}", text))


def registered_keys() -> dict[str, str]:
    """Every erratum a reproduction module lists (its ERRATA: key -> description)."""
    keys: dict[str, str] = {}
    for info in pkgutil.iter_modules(experiments_pkg.__path__):
        module = importlib.import_module(f"{experiments_pkg.__name__}.{info.name}")
        keys.update(getattr(module, "ERRATA", None) or {})
    return keys


def cited_keys() -> set[str]:
    """Every string literal in the experiments' code that has the form of an erratum key: a
    reproduction's key, a dash, a name (``"zhao2013-eq42-ill-posed"``)."""
    names = "|".join(map(re.escape, sorted(experiments(), key=len, reverse=True)))
    pattern = re.compile(rf"[\"']((?:{names})-[a-z0-9][a-z0-9-]*)[\"']")
    return {m for path in SOURCE.rglob("*.py") for m in pattern.findall(path.read_text(encoding="utf-8"))}


def test_every_erratum_key_is_an_anchor_of_docs_errata():
    listed = registered_keys()
    cited = cited_keys()
    assert len(cited) >= 5 and cited <= set(listed), cited - set(listed)  # cited somewhere -> described
    missing = sorted(set(listed) - anchors(ERRATA.read_text(encoding="utf-8")))
    assert not missing, f"docs/errata.md has no anchor for {missing} (add <a id=\"KEY\"></a> above the erratum)"


def test_the_anchor_check_can_fail():
    assert "zhao2013-eq42-ill-posed" not in anchors("### The example of eq. 42 is ill-posed as printed\n")
    assert anchors("<a id=\"k-1\"></a>\n## x {#k-2}\n") == {"k-1", "k-2"}


def test_the_page_links_every_explained_cell_to_an_existing_anchor(tmp_path):
    """A page citing every key, its text renamed as the CLI renames it (papers by author and year):
    every link to errata.md ends in an anchor the real file has."""
    from mptrack.cli.reproduce import _named

    listed = registered_keys()
    keys = sorted(listed)
    results = {"key": "x", "paper": "Assimakis & Adam (2014), seed 000", "seed": 1, "figures": {},
               "errata": dict(listed),
               "tables": {"Table 4 (seed 000)": {
                   "title": "speedups (seed 000)", "columns": ["row", *keys],
                   "rows": [["r", *[1.0] * len(keys)]], "paper": [["r", *[2.0] * len(keys)]],
                   "mismatches": [[0, j] for j in range(1, len(keys) + 1)],
                   "explained_by": [[0, j, k] for j, k in enumerate(keys, 1)]}}}
    page = write_reproduction_report(_named(results), tmp_path / "r.html", errata=ERRATA).read_text()
    links = re.findall(r"href='([^']*errata\.md[^']*)'", page)
    assert len(links) == len(keys)
    targets = {link.partition("#")[2] for link in links}
    assert targets == set(keys) and targets <= anchors(ERRATA.read_text(encoding="utf-8"))
    assert all(link.startswith(ERRATA.as_uri() + "#") for link in links)
    assert "seed 000" not in page and "random seed 1" in page
