"""Dataset: atomic records, round trips, resume-safety, clear errors, failed solves never become data."""

from __future__ import annotations

import json

import numpy as np
import pytest
from toy_problem import ToySolver

import seagul_learn.dataset
from seagul_control import _io
from seagul_control._io import atomic_write_bytes, atomic_write_text
from seagul_envs import make_task
from seagul_learn.dataset import Dataset, DatasetError, SolveRecord, training_arrays


@pytest.fixture
def toy():
    return ToySolver(make_task("acrobot"), num_steps=5, fail_above=np.pi + 0.2)


def _record(toy: ToySolver, index: int, x0: float = np.pi) -> SolveRecord:
    x = np.array([x0, 0.1, -0.2, 0.3])
    return SolveRecord.from_result(toy.solve(x, 5.0), index, "uniform", chain=-1, step=0)


def test_round_trip_preserves_every_field(tmp_path, toy):
    ds = Dataset.open(tmp_path / "d", "acrobot", meta={"solver": "toy"})
    rec = _record(toy, 3)
    rec.chain, rec.step = 2, 4
    ds.write(rec)
    back = Dataset.open(tmp_path / "d").read(3)
    for name, value in vars(rec).items():
        got = getattr(back, name)
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(got, value)
        else:
            assert got == value and type(got) is type(value), name
    # portable: plain npz without pickles, readable by numpy alone
    with np.load(ds.record_path(3), allow_pickle=False) as raw:
        assert str(raw["status"]) == "Solve_Succeeded" and raw["states"].shape == (6, 4)


def test_indices_ignore_half_written_temp_files_and_open_cleans_them(tmp_path, toy):
    ds = Dataset.open(tmp_path / "d", "acrobot")
    ds.write(_record(toy, 0))
    stray = ds.records_dir / ".tmp-abc.npz"
    stray.write_bytes(b"half a record")
    assert ds.indices() == [0] and len(ds) == 1 and 0 in ds and 1 not in ds
    Dataset.open(tmp_path / "d")
    assert not stray.exists()


def test_refuses_duplicate_index(tmp_path, toy):
    ds = Dataset.open(tmp_path / "d", "acrobot")
    ds.write(_record(toy, 0))
    with pytest.raises(DatasetError, match="record 0 already exists"):
        ds.write(_record(toy, 0))


def test_failed_solves_are_stored_but_never_training_data(tmp_path, toy):
    ds = Dataset.open(tmp_path / "d", "acrobot")
    ds.write(_record(toy, 0))
    ds.write(_record(toy, 1, x0=np.pi + 0.25))  # in the toy's failure region
    recs = ds.records()
    assert [r.success for r in recs] == [True, False]
    assert recs[1].status == "Infeasible_Problem_Detected"
    arrays = training_arrays(recs)
    assert len(arrays) == 6 and set(arrays.solve_index.tolist()) == {0}
    np.testing.assert_array_equal(arrays.knot, np.arange(6))
    np.testing.assert_array_equal(arrays.value, recs[0].cost_to_go)
    np.testing.assert_array_equal(arrays.grad_x, recs[0].knot_grads)
    init = arrays.initial()
    assert len(init) == 1 and init.value[0] == recs[0].value
    assert len(training_arrays([recs[1]], nx=4)) == 0


def test_open_errors_name_the_problem(tmp_path, toy):
    with pytest.raises(DatasetError, match="not a seagul dataset"):
        Dataset.open(tmp_path / "missing")
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "dataset.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(DatasetError, match="not a seagul dataset"):
        Dataset.open(tmp_path / "foreign")
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "dataset.json").write_text("{not json")
    with pytest.raises(DatasetError, match="corrupt"):
        Dataset.open(tmp_path / "broken")
    Dataset.open(tmp_path / "d", "acrobot", meta={"a": 1})
    with pytest.raises(DatasetError, match="holds task 'acrobot', not 'glider'"):
        Dataset.open(tmp_path / "d", "glider")
    with pytest.raises(DatasetError, match="other settings"):
        Dataset.open(tmp_path / "d", "acrobot", meta={"a": 2})
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(DatasetError, match="not empty"):
        Dataset.open(tmp_path / "full", "acrobot")


def test_corrupt_record_is_reported(tmp_path, toy):
    ds = Dataset.open(tmp_path / "d", "acrobot")
    ds.write(_record(toy, 7))
    ds.record_path(7).write_bytes(b"garbage")
    with pytest.raises(DatasetError, match=r"solve-000007\.npz.*corrupt"):
        ds.read(7)


# ------------------------------------------------------------------------------------------ the atomic writer
def test_atomic_writes_round_trip_and_leave_no_temp_files(tmp_path):
    target = tmp_path / "new" / "dir" / "file.bin"
    atomic_write_bytes(target, b"\x00\x01 payload")
    assert target.read_bytes() == b"\x00\x01 payload"
    atomic_write_text(target, "replaced: \u03c4")
    assert target.read_text(encoding="utf-8") == "replaced: \u03c4"
    assert [p.name for p in target.parent.iterdir()] == ["file.bin"]
    # The learning code's writers are the one shared helper (torch-free, importable from every package).
    assert seagul_learn.dataset.atomic_write_bytes is atomic_write_bytes
    assert seagul_learn.dataset.atomic_write_text is atomic_write_text


def test_atomic_writes_get_the_umask_mode_and_keep_an_existing_files_mode(tmp_path):
    """Not the temporary file's owner-only 0600: reports and networks stay readable as ``open`` would make them."""
    import os
    import stat

    mask = os.umask(0o022)
    os.umask(mask)
    target = tmp_path / "report.html"
    atomic_write_text(target, "new")
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~mask
    target.chmod(0o640)
    atomic_write_text(target, "again")
    assert stat.S_IMODE(target.stat().st_mode) == 0o640


@pytest.mark.parametrize("failing", ["write", "fsync", "replace"])
def test_failed_atomic_write_leaves_the_old_file_intact(tmp_path, monkeypatch, failing):
    target = tmp_path / "state.json"
    atomic_write_text(target, '{"old": true}')

    class Boom(OSError):
        pass

    def boom(*args, **kwargs):
        raise Boom(f"simulated {failing} failure")

    if failing == "write":
        # A payload that fails half-way through the write (e.g. a full disk) after some bytes reached the temp file.
        real_fdopen = _io.os.fdopen

        class HalfFile:
            def __init__(self, fh):
                self.fh = fh

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                self.fh.close()

            def write(self, data):
                self.fh.write(data[: len(data) // 2])
                raise Boom("No space left on device")

        monkeypatch.setattr(_io.os, "fdopen", lambda fd, mode: HalfFile(real_fdopen(fd, mode)))
    else:
        monkeypatch.setattr(_io.os, failing, boom)
    with pytest.raises(Boom):
        atomic_write_text(target, '{"new": "a longer replacement that must never be seen torn"}')
    monkeypatch.undo()
    assert target.read_text() == '{"old": true}'
    assert [p.name for p in tmp_path.iterdir()] == ["state.json"]  # the temp file was removed


def test_failed_record_write_keeps_the_dataset_readable(tmp_path, toy, monkeypatch):
    ds = Dataset.open(tmp_path / "d", "acrobot")
    ds.write(_record(toy, 0))

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_io.os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space left"):
        ds.write(_record(toy, 1))
    monkeypatch.undo()
    assert ds.indices() == [0] and not list(ds.records_dir.glob(".tmp-*"))
    assert ds.read(0).index == 0


def test_datasets_created_at_once_by_many_workers_are_one(tmp_path):
    """Workers that create the same new dataset at once (a validation cache filled by parallel training runs) all
    open it: none sees a half-made directory ("exists and is not empty") and no staging directory is left."""
    import threading

    for trial in range(10):
        path = tmp_path / f"validation-{trial}"
        barrier = threading.Barrier(8)
        opened, errors = [], []

        def create(path=path, barrier=barrier, opened=opened, errors=errors):
            barrier.wait()
            try:
                opened.append(Dataset.open(path, "acrobot", meta={"solver": "s"}))
            except Exception as exc:
                errors.append(exc)

        threads = [threading.Thread(target=create) for _ in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not errors, errors
        assert len(opened) == 8 and all(d.meta == {"solver": "s"} for d in opened)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"validation-{i}" for i in range(10)]
