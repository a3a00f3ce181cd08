"""Input and output of real data: schemas and validation of position-fix logs
(CSV, Parquet, GPX, TCX, FIT, NMEA 0183, GeoJSON), cellular measurement logs and OpenCelliD cell
tables, with column names and units recognised (:class:`ReadOptions`); WGS-84 <-> local ENU
(compiled, one origin per row); atomic Parquet/CSV/GeoJSON/GPX/GeoParquet writers and their readers
(one module per format, reader and writer together).

Errors name the file, the row and the column (:class:`mptrack.errors.DataError`);
with ``on_error="skip"`` bad rows are dropped and counted in a :class:`ReadReport`.
"""

from .._core.moved import moved_names
from ._geodesy import LocalFrame, enu_to_geodetic, geodetic_to_enu
from ._gpx import NAMESPACE as GPX_EXTENSION_NAMESPACE
from ._formats import FORMATS, Skipped, input_format
from ._interpret import ReadOptions
from ._inputs import input_label, input_name, input_paths, resolve_input
from ._readers import (InputNotSorted, input_columns, iter_track_chunks, iter_tracks, read_cells, read_chunks,
                       read_table)
from ._schema import CELLS, FIXES, MEASUREMENTS, ON_ERROR, Column, ReadReport, Schema, cell_key
from ._outputs import OUTPUT_FORMATS, output_format, read_output, write_table

__all__ = [
    "Skipped",
    "Column",
    "Schema",
    "FIXES",
    "MEASUREMENTS",
    "CELLS",
    "ON_ERROR",
    "ReadReport",
    "ReadOptions",
    "InputNotSorted",
    "cell_key",
    "FORMATS",
    "input_format",
    "resolve_input",
    "input_label",
    "input_name",
    "input_paths",
    "read_chunks",
    "read_table",
    "input_columns",
    "iter_tracks",
    "iter_track_chunks",
    "read_cells",
    "LocalFrame",
    "geodetic_to_enu",
    "enu_to_geodetic",
    "OUTPUT_FORMATS",
    "GPX_EXTENSION_NAMESPACE",
    "output_format",
    "write_table",
    "read_output",
]

#: names that moved to mptrack.runs, the one home of chunked runs (issue 34)
__getattr__ = moved_names(__name__, {"PartStore": "mptrack.runs"})
