"""mptrack.runs, the one home of chunked runs: chunks, the chunk runner (resume without loss or
duplication), part files and the part store of an output, the outputs of a resumable run, and the
names that moved here (served from mptrack.batch and mptrack.io for one release)."""

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mptrack import batch, io, runs
from mptrack.errors import DataError, DTypeError, OutputError, ParameterError
from mptrack.runs import PartStore


def _table():
    return pd.DataFrame({"track_id": ["a", "a", "b"], "t": [0.0, 1.0, 0.0], "lat": [45.0, 45.001, 46.0],
                         "lon": [13.0, 13.001, 14.0], "nis": [np.nan, 1.5, 0.3],
                         "time": pd.to_datetime([0, 1, 0], unit="s", utc=True)})


class FlakyTask:
    """Counts its calls in files (works across processes); fails on chunk ``fail_at`` if asked."""

    def __init__(self, log_dir, fail_at=None):
        self.log_dir, self.fail_at = str(log_dir), fail_at

    def __call__(self, chunk):
        if chunk.index == self.fail_at:
            raise RuntimeError("interrupted")
        Path(self.log_dir, f"call-{chunk.index}-{len(list(Path(self.log_dir).iterdir()))}").touch()
        rng = chunk.generators()
        return pd.DataFrame({"item": np.arange(chunk.start, chunk.stop),
                             "value": [g.standard_normal() for g in rng]})


def test_resume_after_interruption_loses_and_duplicates_nothing(tmp_path):
    log = tmp_path / "log"
    log.mkdir()
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="interrupted"):
        runs.run_chunks(FlakyTask(log, fail_at=2), 10, chunk_size=2, seed=5, out_dir=out)
    assert sorted(p.name for p in out.glob("*.parquet")) == ["chunk-000000.parquet", "chunk-000001.parquet"]
    assert not list(out.glob(".*"))        # no temporary left behind
    result = runs.run_chunks(FlakyTask(log), 10, chunk_size=2, seed=5, out_dir=out)
    calls = sorted(p.name.split("-")[1] for p in log.iterdir())
    assert calls == ["0", "1", "2", "3", "4"]          # each chunk computed exactly once
    assert list(result["item"]) == list(range(10))    # nothing lost, nothing twice
    fresh = runs.run_chunks(FlakyTask(tmp_path), 10, chunk_size=2, seed=5)
    pd.testing.assert_frame_equal(result, fresh, check_exact=True)
    again = runs.run_chunks(FlakyTask(log, fail_at=0), 10, chunk_size=2, seed=5, out_dir=out)
    pd.testing.assert_frame_equal(result, again, check_exact=True)   # all skipped: nothing recomputed


def test_runner_argument_errors():
    with pytest.raises(ParameterError, match="executor: expected one of"):
        runs.run_chunks(FlakyTask("."), 4, chunk_size=2, executor="threads")
    with pytest.raises(ParameterError, match="chunk_size: expected an integer >= 1"):
        runs.run_chunks(FlakyTask("."), 4, chunk_size=0)
    with pytest.raises(ParameterError, match="data: expected 4 leading rows"):
        runs.run_chunks(FlakyTask("."), 4, chunk_size=2, data=np.zeros(3))
    with pytest.raises(DTypeError, match="task: expected a pandas.DataFrame"):
        runs.run_chunks(lambda c: c.size, 4, chunk_size=2)
    with pytest.raises(ParameterError, match="seed: this study was started without a seed"):
        runs.make_chunks(4, 2)[0].generators()


def test_part_store_streams_its_parts_in_order_and_cleans_up(tmp_path):
    import pyarrow as pa
    import pyarrow.feather as feather

    store = PartStore(tmp_path / "o.parquet")
    store.dir.mkdir()
    for i, part in ((1, _table().iloc[2:]), (0, _table().iloc[:2])):  # written out of order
        feather.write_feather(pa.Table.from_pandas(part, preserve_index=False),
                              runs.part_path(store.dir, "points", i, "arrow"))
    assert [p.name for p in store.parts("points")] == ["points-000000.arrow", "points-000001.arrow"]
    (store.dir / "manifest.json").write_text("{}")
    results = [{"points": runs.part_path(store.dir, "points", i, "arrow")} for i in (0, 1)]
    files = store.check(results)
    assert files == {"points": store.parts("points")}
    store.finish(files["points"])
    assert pd.read_parquet(tmp_path / "o.parquet")["track_id"].tolist() == ["a", "a", "b"]
    store.discard()
    assert not store.dir.exists()
    with pytest.raises(ParameterError, match="unknown output format"):
        PartStore(tmp_path / "o.xlsx")
    store.dir.mkdir()
    (store.dir / "manifest.json").write_text("{}")
    feather.write_feather(pa.Table.from_pandas(_table(), preserve_index=False), results[1]["points"])
    with pytest.raises(OutputError, match=r"o.parquet: 1 of the 2 part files of this run vanished .*\(first: "
                                          r"points-000000\.arrow"):
        store.check(results)
    assert not store.dir.exists()  # a store that lost parts is not kept for a resume



def test_a_part_that_is_not_one_is_a_data_error_naming_it(tmp_path):
    bad = tmp_path / "points-000000.arrow"
    bad.write_text("not arrow")
    with pytest.raises(DataError, match="cannot read the part") as exc:
        runs.read_part(bad)
    assert exc.value.file == bad


class _Stop(Exception):
    """A crash inside a run (not an mptrack error)."""


@pytest.mark.parametrize("stop, kept", [(KeyboardInterrupt, True), (OSError, True), (_Stop, True),
                                        (ParameterError, False), (DataError, False)])
def test_resumable_outputs_keep_finished_chunks_only_when_a_rerun_can_use_them(tmp_path, stop, kept):
    """Ctrl-C, an OS failure or a crash keep the finished parts for a resume; bad input or options (an
    mptrack error) leave nothing; the lock is held inside and released after, either way."""
    out = tmp_path / "t.parquet"
    with pytest.raises(stop):
        with runs.resumable_outputs(out, resume=False, last_part="tracks") as store:
            assert runs.lock_path(out).exists()
            store.dir.mkdir()
            runs.part_path(store.dir, "tracks", 0, "arrow").write_bytes(b"")
            raise stop("stopped")
    assert not runs.lock_path(out).exists()
    assert store.dir.exists() == kept
    if kept:   # resumed and stopped by bad input: the parts it came to resume stay
        with pytest.raises(ParameterError):
            with runs.resumable_outputs(out, resume=True, last_part="tracks") as again:
                assert [p.name for p in again.resumed] == ["tracks-000000.arrow"]
                raise ParameterError("q: bad")
        assert store.dir.exists()
        with runs.resumable_outputs(out, resume=False, last_part="tracks") as fresh:  # not resumed: emptied
            assert fresh.resumed == [] and not fresh.dir.exists()


@pytest.mark.parametrize("old, names", [(batch, ("Chunk", "make_chunks", "run_chunks", "run_stream", "part_path",
                                                 "read_part", "EXECUTORS")),
                                        (io, ("PartStore",))])
def test_moved_names_still_import_from_their_old_package_with_a_warning(old, names):
    for name in names:
        assert name not in old.__all__ and name in runs.__all__
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            value = getattr(old, name)
        assert value is getattr(runs, name)
        assert [w.category for w in caught] == [DeprecationWarning]
        assert f"{old.__name__}.{name} moved to mptrack.runs.{name}" in str(caught[0].message)
