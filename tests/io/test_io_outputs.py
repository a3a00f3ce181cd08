"""Output formats on real tracked data: each read back equals the Parquet output; GeoJSON is valid
RFC 7946 and compact, GPX loads in gpxpy, GeoParquet in geopandas."""

import json
import struct

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from _data import REAL_TRACES
from mptrack.errors import DataError, ParameterError
from mptrack.io import OUTPUT_FORMATS, read_output, write_table
from mptrack.tracking import track
from mptrack.cli import app

FORMATS = ["parquet", "csv", "geojson", "gpx", "geoparquet"]
ODD_ID = 'car "2" <&> ü'  # a track id that needs escaping in JSON and XML


@pytest.fixture(scope="module")
def points():
    """The point tables of two real recordings (car, bike), a one-point track and a track whose id needs
    escaping, with two pass-through columns (elevation_m, speed) standing for the input's extras."""
    car, bike = (track(REAL_TRACES[k]) for k in ("car", "bike"))
    car.attrs, bike.attrs = {}, {}
    odd = car.iloc[:30].assign(track_id=ODD_ID)
    single = bike.iloc[:1].assign(track_id="single")
    df = pd.concat([car, odd, bike, single], ignore_index=True)
    rng = np.random.default_rng(13)
    df["elevation_m"] = 100.0 + rng.normal(0, 30, len(df))
    df["speed"] = np.abs(rng.normal(8, 3, len(df)))
    return df


@pytest.fixture(scope="module")
def written(points, tmp_path_factory):
    d = tmp_path_factory.mktemp("out")
    return {fmt: write_table(points, d / f"points.{fmt}") for fmt in FORMATS}


def _tolerance(fmt: str, column: str) -> float:
    """How close a float column of ``fmt`` reads back: positions to 1e-7 degrees in GeoJSON and GPX,
    GeoJSON's other floats to 6 decimals (degree columns 7), everything else exactly."""
    if fmt == "geojson":
        return 5e-8 if column in ("lat", "lon", "origin_lat", "origin_lon", "meas_lat", "meas_lon",
                                  "ell_azimuth_deg") else 5e-7
    if fmt == "gpx" and column in ("lat", "lon"):
        return 5e-8
    return 0.0


@pytest.mark.parametrize("fmt", FORMATS[1:])
def test_each_format_reads_back_as_the_parquet_output(points, written, fmt):
    ref = read_output(written["parquet"])
    back = read_output(written[fmt])
    assert list(back.columns) == list(ref.columns) == list(points.columns)
    assert len(back) == len(ref) == len(points)
    for col in ref.columns:
        want, got = ref[col], back[col]
        if want.dtype.kind == "f":
            tol = _tolerance(fmt, col)
            np.testing.assert_array_equal(np.isnan(got.to_numpy(float)), np.isnan(want.to_numpy()), err_msg=col)
            np.testing.assert_allclose(got.to_numpy(float), want.to_numpy(), rtol=0, atol=tol, err_msg=col)
            if tol and col in ("lat", "lon", "east_m"):  # the rounding is really there
                assert not np.array_equal(got.to_numpy(float), want.to_numpy(), equal_nan=True), col
        else:
            pd.testing.assert_series_equal(got, want, check_dtype=fmt != "csv", obj=col)
    if fmt != "csv":  # CSV cannot tell 0.0 from 0: float columns of whole numbers read back as int
        assert back.dtypes.to_dict() == ref.dtypes.to_dict()


def test_parquet_output_is_the_table(points, written):
    back = read_output(written["parquet"])
    pd.testing.assert_frame_equal(back, points, check_dtype=False)
    assert back["time"].dtype == "datetime64[ns, UTC]" and back["time"].iloc[0] == pd.Timestamp(
        "2020-12-18T06:15:50Z")


def test_geojson_is_valid_compact_and_one_feature_per_track(points, written):
    geojson = pytest.importorskip("geojson")
    text = written["geojson"].read_text(encoding="utf-8")
    fc = geojson.loads(text)
    assert fc.is_valid and fc["type"] == "FeatureCollection"
    features = json.loads(text)["features"]  # geojson.loads rounds coordinates to 6 decimals
    ids = list(dict.fromkeys(points["track_id"]))
    assert [f["properties"]["track_id"] for f in features] == ids  # once per feature, not per point
    assert [f["geometry"]["type"] for f in features] == ["LineString", "LineString", "LineString", "Point"]
    car = points[points["track_id"] == ids[0]]
    line = features[0]
    assert line["geometry"]["coordinates"][0] == [round(car["lon"].iloc[0], 7), round(car["lat"].iloc[0], 7)]
    props = line["properties"]
    assert props["method"] == "KF-gated" and props["origin_lat"] == round(car["origin_lat"].iloc[0], 7)
    assert props["time"][:2] == ["2020-12-18T06:15:50Z", "2020-12-18T06:16:00Z"] and len(props["time"]) == len(car)
    assert props["flag"][0] == "init" and props["nis"][0] is None and props["nis"][1] == round(car["nis"].iloc[1], 6)
    assert "lat" not in props and "lon" not in props  # in the geometry
    single = features[-1]
    lon, lat = points[["lon", "lat"]].iloc[-1]
    assert single["geometry"]["coordinates"] == [round(lon, 7), round(lat, 7)]
    assert single["properties"]["flag"] == "init"
    assert features[1]["properties"]["track_id"] == ODD_ID
    per_point = written["geojson"].stat().st_size / len(points)
    assert per_point <= 300, per_point  # was ~876 with a Feature per point


def test_geojson_splits_tracks_at_missing_positions(tmp_path):
    """A row without a finite position is no vertex: the track is split into features, the run without
    positions has a null geometry and its lat/lon in the properties; the file stays strict JSON."""
    df = pd.DataFrame({"track_id": ["a"] * 5, "time": pd.date_range("2024-01-01", periods=5, freq="s", tz="UTC"),
                       "lat": [45.0, 45.1, np.nan, np.inf, 45.4], "lon": [13.0, 13.1, 13.2, 13.3, 13.4],
                       "speed": [1.0, 2.0, np.nan, 4.0, 5.0]})
    path = write_table(df, tmp_path / "gaps.geojson")
    fc = json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    kinds = [f["geometry"] and f["geometry"]["type"] for f in fc["features"]]
    assert kinds == ["LineString", None, "Point"]
    gap = fc["features"][1]["properties"]
    assert gap["lat"] == [None, None] and gap["lon"] == [13.2, 13.3] and gap["speed"] == [None, 4.0]
    back = read_output(path)
    np.testing.assert_array_equal(back["lat"], [45.0, 45.1, np.nan, np.nan, 45.4])  # inf reads back as NaN
    np.testing.assert_array_equal(back["speed"], df["speed"])
    pd.testing.assert_series_equal(back["time"], df["time"].astype("datetime64[ns, UTC]"))
    # local x/y output (no lat/lon columns): every feature unlocated, nothing lost
    xy = df.drop(columns=["lat", "lon"]).assign(x=np.arange(5.0))
    back = read_output(write_table(xy, tmp_path / "xy.geojson"))
    pd.testing.assert_frame_equal(back, xy.astype({"time": "datetime64[ns, UTC]"}))


@pytest.mark.parametrize("fmt", ["geojson", "gpx", "geoparquet", "csv"])
def test_streamed_chunks_write_the_same_file(points, written, tmp_path, fmt):
    """write_table over chunks of whole tracks (as track_file streams its parts) gives the same bytes (CSV:
    the same table; it quotes text only in the chunks that need it)."""
    ids = points["track_id"].to_numpy()
    cuts = np.r_[0, np.flatnonzero(ids[1:] != ids[:-1]) + 1, len(ids)]
    chunks = [points.iloc[a:b] for a, b in zip(cuts[:-1], cuts[1:])]
    path = write_table(iter(chunks), tmp_path / f"chunks.{fmt}")
    if fmt in ("geoparquet", "csv"):
        pd.testing.assert_frame_equal(read_output(path), read_output(written[fmt]))
    else:
        assert path.read_bytes() == written[fmt].read_bytes()


@pytest.mark.parametrize("fmt", FORMATS)
def test_an_empty_table_keeps_its_columns(points, tmp_path, fmt):
    back = read_output(write_table(points.iloc[:0], tmp_path / f"empty.{fmt}"))
    assert len(back) == 0 and list(back.columns) == list(points.columns)


def test_gpx_loads_in_gpxpy_with_times_elevation_and_extensions(points, written):
    import gpxpy

    from mptrack.io import GPX_EXTENSION_NAMESPACE as NAMESPACE

    with open(written["gpx"], encoding="utf-8") as fh:
        gpx = gpxpy.parse(fh)
    ids = list(dict.fromkeys(points["track_id"]))
    assert [t.name for t in gpx.tracks] == ids
    pts = [p for t in gpx.tracks for s in t.segments for p in s.points]
    assert len(pts) == len(points) and all(len(t.segments) == 1 for t in gpx.tracks)
    np.testing.assert_allclose([p.latitude for p in pts], points["lat"], rtol=0, atol=5e-8)
    np.testing.assert_allclose([p.longitude for p in pts], points["lon"], rtol=0, atol=5e-8)
    np.testing.assert_array_equal([p.elevation for p in pts], points["elevation_m"])
    assert [pd.Timestamp(p.time) for p in pts] == list(points["time"])
    ext = {e.tag: e.text for e in pts[1].extensions}
    row = points.iloc[1]
    assert float(ext[f"{{{NAMESPACE}}}east_m"]) == row["east_m"] and ext[f"{{{NAMESPACE}}}flag"] == row["flag"]
    assert float(ext[f"{{{NAMESPACE}}}speed"]) == row["speed"] and ext[f"{{{NAMESPACE}}}gap"] == "false"
    assert f"{{{NAMESPACE}}}lat" not in ext and f"{{{NAMESPACE}}}time" not in ext


def test_gpx_refuses_rows_without_a_position(points, tmp_path):
    bad = points.copy()
    bad.loc[5, "lat"] = np.nan
    with pytest.raises(ParameterError, match=r"1 rows have none, the first is row 6 .*2020-12-18 07:24:29"):
        write_table(bad, tmp_path / "bad.gpx")
    with pytest.raises(ParameterError, match="needs the columns lat and lon"):
        write_table(bad.drop(columns=["lat"]), tmp_path / "bad.gpx")
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_gpx_column_names_that_are_not_xml_names_round_trip(tmp_path):
    df = pd.DataFrame({"track_id": ["a", "a"], "lat": [45.0, 45.1], "lon": [13.0, 13.1],
                       "speed (km/h)": [10.5, 11.0], "name": ["x<y", "z"]})
    path = write_table(df, tmp_path / "names.gpx")
    text = path.read_text()
    assert "<mptrack:column3>10.5</mptrack:column3>" in text and "<mptrack:name>x&lt;y</mptrack:name>" in text
    pd.testing.assert_frame_equal(read_output(path), df)


def test_geoparquet_reads_as_a_geodataframe(points, written):
    gpd = pytest.importorskip("geopandas")
    gdf = gpd.read_parquet(written["geoparquet"])
    assert isinstance(gdf, gpd.GeoDataFrame) and gdf.geometry.name == "geometry"
    assert (gdf.geom_type == "Point").all() and gdf.crs.to_string() == "OGC:CRS84"
    np.testing.assert_array_equal(gdf.geometry.x, points["lon"])
    np.testing.assert_array_equal(gdf.geometry.y, points["lat"])
    geo = json.loads(pq.read_metadata(written["geoparquet"]).metadata[b"geo"])
    assert geo["version"] == "1.1.0" and geo["primary_column"] == "geometry"
    assert geo["columns"]["geometry"]["encoding"] == "WKB"
    assert geo["columns"]["geometry"]["bbox"] == [points["lon"].min(), points["lat"].min(), points["lon"].max(),
                                                  points["lat"].max()]
    wkb = pd.read_parquet(written["geoparquet"])["geometry"].iloc[0]
    assert wkb == struct.pack("<BIdd", 1, 1, points["lon"].iloc[0], points["lat"].iloc[0])


def test_geoparquet_rows_without_a_position_have_no_geometry(tmp_path):
    gpd = pytest.importorskip("geopandas")
    df = pd.DataFrame({"track_id": ["a", "a", "a"], "lat": [45.0, np.nan, 45.2], "lon": [13.0, 13.1, 13.2]})
    gdf = gpd.read_parquet(write_table(df, tmp_path / "g.geoparquet"))
    assert gdf.geometry.isna().tolist() == [False, True, False]
    pd.testing.assert_frame_equal(read_output(tmp_path / "g.geoparquet"), df)
    with pytest.raises(ParameterError, match="needs the columns lat and lon"):
        write_table(df.drop(columns=["lon"]), tmp_path / "h.geoparquet")


def test_plain_parquet_has_no_geometry(written):
    assert "geometry" not in pq.read_schema(written["parquet"]).names
    assert b"geo" not in (pq.read_metadata(written["parquet"]).metadata or {})


def test_suffixes_are_registered_and_unknown_ones_named():
    assert {OUTPUT_FORMATS[s] for s in (".gpx", ".geoparquet", ".geojson", ".csv", ".parquet")} == set(FORMATS)
    with pytest.raises(ParameterError, match=r"unknown output format '\.kml'"):
        read_output("x.kml")
    with pytest.raises(DataError, match="file not found"):
        read_output("missing.gpx")


def test_read_output_names_a_file_it_cannot_read(tmp_path):
    (tmp_path / "x.geojson").write_text("{not json")
    with pytest.raises(DataError, match="x.geojson.*cannot be read as a GeoJSON"):
        read_output(tmp_path / "x.geojson")
    (tmp_path / "y.gpx").write_text(REAL_TRACES["car"].read_text())
    with pytest.raises(DataError, match="not written by mptrack"):
        read_output(tmp_path / "y.gpx")


@pytest.mark.parametrize("fmt", ["gpx", "geoparquet"])
def test_track_command_writes_the_new_formats(tmp_path, fmt):
    out = tmp_path / f"t.{fmt}"
    res = CliRunner().invoke(app, ["track", str(REAL_TRACES["car"]), "--out", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    back = read_output(out)
    assert len(back) == 104 and back["track_id"].unique().tolist() == ["2020-12-18 07:24:29"]


@pytest.mark.parametrize("suffix", [".parquet", ".csv", ".geojson"])
def test_a_tracked_frame_writes_without_warnings(tmp_path, suffix):
    """mptrack.track keeps its run summaries (tables) in the frame's attrs; writing the frame warned
    that pyarrow cannot serialise them (they are not file metadata); the frame keeps them."""
    import warnings

    import mptrack
    pts = mptrack.track(mptrack.simulate("gps", 1, seed=2, duration_s=20.0))
    assert isinstance(pts.attrs["tracks"], pd.DataFrame)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_table(pts, tmp_path / f"p{suffix}")
    assert "tracks" in pts.attrs
