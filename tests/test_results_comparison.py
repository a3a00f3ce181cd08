"""results.json comparison counts: matched / differing-explained / differing-unexplained."""

import pytest

from mptrack.experiments import Reproduction, Table, differences


def _table():
    t = Table(title="t", columns=["row", "a", "b"], rows=[["x", 1.0, 2.0], ["y", 3.0, "f"]],
              paper=[["x", 1.0, 2.5], ["y", None, "g"]])
    t.explain([(0, 2)], "e1")
    t.explain([(0, 1)], "e1")  # a matching cell keeps counting as matched
    return t


def test_counts_of_a_table():
    t = _table()
    assert t.mismatches() == [(0, 2), (1, 2)]
    assert t.comparison() == {"compared": 3, "matched": 1, "differing_explained": 1, "differing_unexplained": 1}
    assert t.explained_by() == [(0, 2, "e1")]
    js = t.to_json()
    assert js["explained_by"] == [[0, 2, "e1"]] and js["comparison"] == t.comparison()


def test_counts_of_a_reproduction_and_errata_check():
    rep = Reproduction(key="k", paper="p", seed=1, parameters={},
                       tables={"T": _table(), "own": Table(title="o", columns=["c", "v"], rows=[["r", 1]])})
    with pytest.raises(ValueError, match="e1"):
        rep.to_json()
    rep.errata["e1"] = "docs/errata.md, a section"
    js = rep.to_json()
    assert js["comparison"] == {"compared": 3, "matched": 1, "differing_explained": 1, "differing_unexplained": 1}
    assert js["errata"] == {"e1": "docs/errata.md, a section"}
    assert "comparison" not in js["tables"]["own"]
    assert differences(rep) == {"T": [(0, 2), (1, 2)]}
    assert differences(rep, unexplained=True) == {"T": [(1, 2)]}


def test_uncounted_columns_are_shown_but_not_compared():
    """Inputs and labels a table repeats from the paper are neither compared nor counted."""
    t = Table(title="t", columns=["row", "input", "label", "result"],
              rows=[["x", 52, "A", 0.5], ["y", 36, "B", 0.7]], paper=[["x", 52, "A", 0.5], ["y", 35, "B", 0.9]],
              uncounted=("input", "label"))
    assert t.mismatches() == [(1, 3)]
    assert t.comparison() == {"compared": 2, "matched": 1, "differing_explained": 0, "differing_unexplained": 1}
    assert t.to_json()["uncounted"] == ["input", "label"]
    with pytest.raises(ValueError, match="uncounted"):
        Table(title="t", columns=["row", "a"], rows=[["x", 1]], uncounted=("row",))
