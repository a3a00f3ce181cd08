"""Self-contained offline HTML reports of tracking runs (embedded PNG figures)."""

from ._html import TRACK_COLOR, write_report

__all__ = ["write_report", "TRACK_COLOR"]
