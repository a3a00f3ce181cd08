"""Self-contained HTML reports (one file, works offline): tracking runs on an interactive map with
time plots, data quality and a table of every track; paper reproductions beside the published
numbers."""

from ._live import live_map_page
from ._reproduction import explained_cells, uncounted_columns, write_reproduction_report
from ._tracks import LAYERS, PALETTE, REPORT_COLUMNS, report_points, write_report

__all__ = ["write_report", "live_map_page", "report_points", "write_reproduction_report", "explained_cells",
           "uncounted_columns", "PALETTE", "REPORT_COLUMNS", "LAYERS"]
