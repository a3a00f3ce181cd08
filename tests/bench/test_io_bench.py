"""The I/O benchmark suite runs (10^4 fixes) and reports every case next to its pandas anchor."""

import numpy as np

from mptrack.bench import run_suites, suites


def test_io_suite_reports_reading_and_writing_next_to_pandas():
    assert "io" in suites()
    (report,) = run_suites(["io"], quick=True)
    assert report["suite"] == "io"
    assert report["columns"] == ["case", "fixes", "fixes/s", "x pandas"]
    rows = {row[0]: row for row in report["rows"]}
    assert set(rows) == {
        "read csv (mptrack.io.read_chunks)", "read csv (pandas.read_csv)",
        "read parquet (mptrack.io.read_chunks)", "read parquet (pandas.read_parquet)",
        "write parquet (DataFrame.to_parquet)", "write gpx (gpxpy objects)",
        *(f"write {fmt} (mptrack.io.write_table)" for fmt in ("parquet", "csv", "geojson", "gpx", "geoparquet"))}
    assert all(row[1] == 10_000 for row in report["rows"])
    values = np.array([row[2:] for row in report["rows"]], dtype=float)
    assert np.isfinite(values).all() and (values > 0).all()
    assert rows["read csv (pandas.read_csv)"][3] == 1.0 and rows["write parquet (DataFrame.to_parquet)"][3] == 1.0
    assert report["bytes_per_fix"]["geojson"] <= 300  # the size goal holds at any size
    assert any("GeoJSON" in note for note in report["notes"])
