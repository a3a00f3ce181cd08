"""The tracking pipeline: executors give the same bits, Parquet datasets stream like one file, and the
Python API works without files."""

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import mptrack
from mptrack.errors import DataError
from mptrack.tracking import TRACK_COLUMNS, track, track_file


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    """40 simulated tracks (2 % outliers, accuracy column) as one Parquet file."""
    d = tmp_path_factory.mktemp("pipe")
    df = mptrack.simulate("gps", tracks=40, seed=9, duration_s=200.0)
    df.to_parquet(d / "log.parquet", index=False)
    return d / "log.parquet", df


def test_every_executor_writes_the_same_bits(tmp_path, log):
    path, _ = log
    outs = {}
    for executor in ("serial", "processes", "dask"):
        out = tmp_path / f"{executor}.parquet"
        kwargs = {}
        if executor == "dask":
            from dask.distributed import Client, LocalCluster

            cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None)
            kwargs["client"] = Client(cluster)
        try:
            summary = track_file(path, out, chunk_rows=700, executor=executor, max_workers=2,
                                 track_summary=tmp_path / f"{executor}.tracks.parquet", **kwargs)
        finally:
            if kwargs:
                kwargs["client"].close()
                cluster.close()
        assert summary["chunks"] > 3 and summary["tracks"] == 40
        outs[executor] = (pd.read_parquet(out), pd.read_parquet(tmp_path / f"{executor}.tracks.parquet"))
    for executor in ("processes", "dask"):
        for got, want in zip(outs[executor], outs["serial"]):
            pd.testing.assert_frame_equal(got, want, check_exact=True)  # NaN == NaN, every other bit equal


def test_a_parquet_dataset_tracks_like_one_file(tmp_path, log):
    """A directory of Parquet files (hive-partitioned by a column or not) streams, in file order, like
    the single file; memory follows the chunk, not the dataset."""
    path, df = log
    plain = tmp_path / "plain"
    plain.mkdir()
    ids = df["track_id"].unique()
    for i, part in enumerate(np.array_split(ids, 4)):
        df[df["track_id"].isin(part)].to_parquet(plain / f"part-{i}.parquet", index=False)
    hive = tmp_path / "hive"
    table = pa.Table.from_pandas(df.assign(day=np.where(df["track_id"] < ids[20], "d1", "d2")), preserve_index=False)
    pq.write_to_dataset(table, hive, partition_cols=["day"])
    one = track_file(path, tmp_path / "one.parquet", chunk_rows=500)
    for name, directory in (("plain", plain), ("hive", hive)):
        summary = track_file(directory, tmp_path / f"{name}.parquet", chunk_rows=500)
        assert summary["tracks"] == one["tracks"] and summary["fixes"] == one["fixes"]
        got, want = pd.read_parquet(tmp_path / f"{name}.parquet"), pd.read_parquet(tmp_path / "one.parquet")
        if name == "hive":  # the partition key is a column of the dataset, passed through to the output
            assert set(got.pop("day")) == {"d1", "d2"}
        pd.testing.assert_frame_equal(got.sort_values(["track_id", "t"]).reset_index(drop=True),
                                      want.sort_values(["track_id", "t"]).reset_index(drop=True))
    with pytest.raises(DataError, match="no Parquet files"):
        track_file(_empty_dir(tmp_path), tmp_path / "x.parquet")


def _empty_dir(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    return d


def test_python_api_needs_no_files(log):
    path, df = log
    points = mptrack.track(df, smooth=True)
    from_file = track(path, smooth=True)
    pd.testing.assert_frame_equal(points, from_file)
    tracks = points.attrs["tracks"]
    assert list(tracks.columns) == list(TRACK_COLUMNS) and len(tracks) == 40
    assert points.attrs["summary"]["tracks"] == 40 and points["method"].eq("KF-gated+RTS").all()
    # cellular: the simulated cell table comes with the log
    cell_log = mptrack.simulate("urban-3bts", tracks=2, seed=3, duration_s=60.0)
    cells = cell_log.attrs["cells"]
    ct = mptrack.track(cell_log, cells=cells, method="ekf")
    assert ct["track_id"].nunique() == 2 and np.isfinite(ct["east_m"]).all()
    assert set(ct.attrs["tracks"]["track_id"]) == set(cell_log["track_id"])


def test_python_api_errors_name_the_argument_and_row():
    bad = pd.DataFrame({"track_id": ["a", "a"], "time": [0.0, 1.0], "lat": [45.0, 95.0], "lon": [13.0, 13.0]})
    with pytest.raises(DataError) as info:
        mptrack.track(bad)
    assert "<DataFrame>" in str(info.value) and "row 2" in str(info.value) and "'lat'" in str(info.value)
    with pytest.raises(DataError, match="missing column"):
        mptrack.track(bad.drop(columns="time"))
    with pytest.raises(ValueError, match="noise"):
        mptrack.track(bad, noise="per-device")
    with pytest.raises(ValueError, match="sigma: not an option of mptrack.track; did you mean sigma_m"):
        mptrack.track(bad, sigma=5.0)
    with pytest.raises(ValueError, match="chunk_rows"):
        mptrack.track(bad, chunk_rows=0)
    with pytest.raises(DataError, match=r"1 of 2 rows would be dropped, more than the 0 allowed by --max-skip 1%; "
                                        r"1 x lat: outside .*first: row 2"):
        mptrack.track(bad, on_error="skip")
    points = mptrack.track(bad, on_error="skip", max_skip="1")
    assert len(points) == 1 and points.attrs["summary"]["read"]["rows_skipped"] == 1


def test_evaluation_summary_has_the_nis_advice_of_a_run(tmp_path):
    """evaluate_tracks counts the tracks whose mean NIS is far outside its band and says what that means,
    as a tracking run's summary does (the CLI prints it; it used to compute it itself)."""
    from _data import REAL_TRACES

    from mptrack.io import read_output
    from mptrack.tracking import TrackOptions, evaluate_tracks

    run = track_file(REAL_TRACES["car"], tmp_path / "b.parquet", options=TrackOptions(sigma_m=50.0))
    summary, _ = evaluate_tracks(read_output(tmp_path / "b.parquet"))
    assert summary["nis"]["far_low"] == run["nis"]["far_low"] == 1 and summary["nis"]["far_high"] == 0
    assert summary["nis"]["advice"][0].startswith("1 track(s) have a mean NIS far below its band")


def test_truth_of_another_clock_is_named_by_its_offset():
    """Truth whose times are a whole time-zone offset from the estimates' (local time stamps read in two
    zones) matches nothing; the refusal says by how much they differ, and says nothing of zones when no
    offset explains it."""
    from mptrack.tracking import attach_truth

    sim = mptrack.simulate("gps", tracks=1, seed=3, duration_s=120.0)
    points = mptrack.track(sim.drop(columns=["true_lat", "true_lon"]))
    truth = sim[["time", "true_lat", "true_lon"]].rename(columns={"true_lat": "lat", "true_lon": "lon"})
    assert np.isfinite(attach_truth(points, truth)["error_m"]).all()
    for hours, word in ((-2.0, "before"), (5.5, "after")):
        shifted = truth.assign(time=truth["time"] + pd.Timedelta(hours=hours))
        with pytest.raises(DataError, match=f"the truth's times are {abs(hours):g} h {word} the estimates'"):
            attach_truth(points, shifted)
    with pytest.raises(DataError, match=r"is it the truth of this run\?") as e:
        attach_truth(points, truth.assign(time=truth["time"] + pd.Timedelta(seconds=1000)))
    assert "zone" not in str(e.value)
