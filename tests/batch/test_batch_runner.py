"""Studies with the batch filters run in chunks (mptrack.runs): executors agree bitwise, chunking does not
change the numbers, output resumes and refuses another study."""

import numpy as np
import pandas as pd
import pytest

from mptrack import batch, linear
from mptrack.errors import ParameterError
from mptrack.models import assimakis_model_b
from mptrack.sim import simulate_linear

MODEL = assimakis_model_b()


def test_monte_carlo_runs_equal_the_reference_per_run_and_ignore_chunking():
    a = batch.monte_carlo(MODEL, 40, 9, seed=11, chunk_size=4)
    b = batch.monte_carlo(MODEL, 40, 9, seed=11, chunk_size=9)
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert list(a["run"]) == list(range(9))
    truth, z = simulate_linear(MODEL, 40, np.random.default_rng(np.random.SeedSequence(11, spawn_key=(5,))))
    x = linear.steady_state_filter(MODEL, z).x
    np.testing.assert_allclose(a.loc[5, ["rmse_x0", "rmse_x1"]].to_numpy(float),
                               np.sqrt(np.mean((x - truth) ** 2, axis=0)), rtol=1e-12)
    kf = batch.monte_carlo(MODEL, 40, 3, seed=11, chunk_size=2, method="kalman", P0=np.eye(2))
    assert not kf.equals(a.iloc[:3])


def test_dask_and_process_executors_equal_serial_bitwise():
    from dask.distributed import Client, LocalCluster

    serial = batch.monte_carlo(MODEL, 30, 10, seed=3, chunk_size=3)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        on_dask = batch.monte_carlo(MODEL, 30, 10, seed=3, chunk_size=3, executor="dask", client=client)
        z = np.random.default_rng(1).standard_normal((7, 20, 1))
        x = batch.filter_chunked(batch.steady_state_filter, MODEL, z, chunk_size=2, executor="dask",
                                 client=client)
    pd.testing.assert_frame_equal(serial, on_dask, check_exact=True)
    direct = batch.steady_state_filter(MODEL, z)
    np.testing.assert_array_equal(x.x, direct.x)
    np.testing.assert_array_equal(x.P, direct.P)          # the shared steady covariance
    assert x.method == direct.method == "SSKF"
    in_processes = batch.monte_carlo(MODEL, 30, 10, seed=3, chunk_size=3, executor="processes",
                                     max_workers=2)
    pd.testing.assert_frame_equal(serial, in_processes, check_exact=True)


def test_a_different_study_in_the_same_directory_is_refused(tmp_path):
    batch.monte_carlo(MODEL, 10, 4, seed=1, chunk_size=2, out_dir=tmp_path)
    with pytest.raises(ParameterError, match="out_dir: .* different study"):
        batch.monte_carlo(MODEL, 10, 4, seed=2, chunk_size=2, out_dir=tmp_path)


def test_study_argument_errors():
    with pytest.raises(ParameterError, match="method: expected"):
        batch.monte_carlo(MODEL, 10, 4, seed=1, method="fir")


def test_filter_chunked_resumes_and_refuses_other_data(tmp_path):
    z = np.random.default_rng(2).standard_normal((9, 15, 1))
    first = batch.filter_chunked(batch.kalman_filter, MODEL, z, chunk_size=4, out_dir=tmp_path, P0=np.eye(2))
    direct = batch.kalman_filter(MODEL, z, P0=np.eye(2))
    np.testing.assert_array_equal(first.x, direct.x)
    assert first.P is None and first.method == "KF"
    np.testing.assert_array_equal(first.inputs["gains"].P_filt, direct.inputs["gains"].P_filt)
    (tmp_path / "chunk-000001.parquet").unlink()          # as if interrupted
    again = batch.filter_chunked(batch.kalman_filter, MODEL, z, chunk_size=4, out_dir=tmp_path, P0=np.eye(2))
    np.testing.assert_array_equal(first.x, again.x)
    with pytest.raises(ParameterError, match="different study"):
        batch.filter_chunked(batch.kalman_filter, MODEL, z + 1.0, chunk_size=4, out_dir=tmp_path,
                             P0=np.eye(2))
    with pytest.raises(ParameterError, match="different study"):
        batch.filter_chunked(batch.kalman_filter, MODEL, z, chunk_size=4, out_dir=tmp_path, P0=2 * np.eye(2))
