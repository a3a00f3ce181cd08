"""``mptrack filters``: the registered linear filters and the 12 implementations of Assimakis & Adam 2014."""

from __future__ import annotations

from rich.table import Table as RichTable

from ._common import JSON, QUIET, VERBOSE, out, paper_names, print_json

__all__ = ["filters"]


def filters(quiet: bool = QUIET, verbose: bool = VERBOSE, json_out: bool = JSON) -> None:
    """List the registered filters and the 12 implementations of Assimakis & Adam 2014 Table 1."""
    from ..linear import FILTERS, IMPLEMENTATIONS

    specs = [{"name": s.name, "system": s.system, "description": paper_names(s.description)}
             for s in FILTERS.values()]
    imps = [{"number": i.number, "name": i.name, "model": i.model, "system": i.system, "filter": i.filter}
            for i in IMPLEMENTATIONS]
    if json_out:
        print_json({"filters": specs, "implementations": imps})
        return
    if quiet:
        out.print(" ".join(s["name"] for s in specs), highlight=False)
        return
    rt = RichTable(title="Filters", title_justify="left")
    for col in ("name", "system", "description"):
        rt.add_column(col)
    for s in specs:
        rt.add_row(s["name"], s["system"], s["description"])
    out.print(rt)
    rt = RichTable(title="Implementations (Assimakis & Adam 2014, Table 1)", title_justify="left")
    for col in ("#", "name", "model", "system", "filter"):
        rt.add_column(col)
    for i in imps:
        rt.add_row(str(i["number"]), i["name"], i["model"], i["system"], i["filter"])
    out.print(rt)
