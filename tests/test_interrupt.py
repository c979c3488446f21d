"""SIGKILL ``seagul train`` at several points, resume with ``--resume``: the result equals an uninterrupted run.

The real CLI (``python -m seagul_learn.cli train``) and the real trajectory optimizer run in a
subprocess; the test polls the run's ``dataset/records`` directory and kills the process (SIGKILL: no cleanup, no
``finally``) once the k-th record file has appeared, then resumes it. The final dataset (every array of every
record but the wall-clock ``solve_time``), the network weights and the metrics (but ``wall_time``) must be
IDENTICAL to an uninterrupted run with the same seed, and no half-written record may ever be visible under a
record's name.

Speed: the validation set only feeds the metrics (never the dataset or the weights), so the private validation
cache is pre-filled with the toy solver's labels under the real solver's cache key instead of solving 200 NLPs here;
both runs read the same cache, so their metrics are still compared exactly. The default suite kills one run
mid-round; the ``slow`` variant kills during pretraining, right after it and in the last round, and kills a
resumed run again.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from toy_problem import ToySolver

from seagul_envs import make_task
from seagul_learn.dataset import Dataset
from seagul_learn.solving import solver_key
from seagul_learn.training import validation_dataset

PRETRAIN = 5
BUDGET = 20
TOTAL = PRETRAIN + BUDGET  # records of a finished run
TIMEOUT = 300.0  # seconds any one subprocess may take before the test gives up (a hang is a failure)


def _argv(out: Path, cache: Path, resume: bool = False) -> list[str]:
    args = [sys.executable, "-m", "seagul_learn.cli", "train", "--task", "acrobot", "--sampler", "adversarial",
            "--budget", str(BUDGET), "--solves-per-round", "5", "--train-steps-per-round", "50",
            "--pretrain-solves", str(PRETRAIN), "--pretrain-steps", "20", "--adv-max-steps", "3", "--seed", "3",
            "--out", str(out), "--cache-dir", str(cache), "--no-progress", "--recipe", "paper"]  # fmt: skip
    return [*args, "--resume"] if resume else args


def _prefill_validation_cache(cache: Path) -> None:
    """The validation records the real solver's runs will look up, labelled by the toy (metrics only)."""
    task = make_task("acrobot")
    validation_dataset(task, ToySolver(task), solver_key(None), cache)


def _run(out: Path, cache: Path, resume: bool = False) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(_argv(out, cache, resume), capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().splitlines()[-1] == str(out)
    return proc


def _record_names(out: Path) -> list[str]:
    records = out / "dataset" / "records"
    return sorted(p.name for p in records.iterdir()) if records.is_dir() else []


def _kill_after_records(out: Path, cache: Path, k: int, resume: bool) -> int:
    """Start a run, SIGKILL it as soon as ``k`` complete records exist; return how many there were at the kill."""
    proc = subprocess.Popen(_argv(out, cache, resume), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + TIMEOUT
    try:
        while True:
            done = Dataset(out / "dataset", "acrobot", {}).indices() if (out / "dataset").is_dir() else []
            if len(done) >= k:
                os.kill(proc.pid, signal.SIGKILL)
                break
            if proc.poll() is not None:
                pytest.fail(f"run ended (status {proc.returncode}) before record {k}: {proc.stderr.read()[-3000:]}")
            if time.monotonic() > deadline:
                pytest.fail(f"no record {k} after {TIMEOUT} s")
            time.sleep(0.01)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=60)
        assert proc.stderr is not None
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    return len(done)


def _assert_killed_state_is_clean(out: Path, at_least: int) -> None:
    """After a kill: records are consecutive from 0 and every file under a record's name is complete."""
    ds = Dataset(out / "dataset", "acrobot", {})
    indices = ds.indices()
    assert len(indices) >= at_least
    assert indices == list(range(len(indices))), "a record is missing in the middle"
    for i in indices:
        ds.read(i)  # raises DatasetError on a torn file
    names = _record_names(out)
    assert all(n.startswith(("solve-", ".tmp-")) for n in names), names


def _final_arrays(out: Path) -> list[dict[str, np.ndarray]]:
    ds = Dataset.open(out / "dataset")
    return [{k: v for k, v in r.to_arrays().items() if k != "solve_time"} for r in ds.records()]


def _assert_identical_runs(ref: Path, run: Path) -> None:
    ref_arrays, run_arrays = _final_arrays(ref), _final_arrays(run)
    assert len(run_arrays) == len(ref_arrays) == TOTAL
    for i, (a, b) in enumerate(zip(ref_arrays, run_arrays, strict=True)):
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(b[key], a[key], err_msg=f"record {i}: {key}")
    ref_net = torch.load(ref / "network.pt", weights_only=True)["state_dict"]
    run_net = torch.load(run / "network.pt", weights_only=True)["state_dict"]
    assert ref_net.keys() == run_net.keys()
    for key in ref_net:
        assert torch.equal(ref_net[key], run_net[key]), f"network weights differ in {key}"

    def metrics(path: Path) -> list[dict[str, float]]:
        rows = json.loads((path / "metrics.json").read_text())["metrics"]
        return [{k: v for k, v in row.items() if k != "wall_time"} for row in rows]

    assert metrics(run) == metrics(ref)
    # no half-written record survives a resume, under any name
    assert _record_names(run) == [f"solve-{i:06d}.npz" for i in range(TOTAL)]


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """An uninterrupted run and the validation cache it used."""
    root = tmp_path_factory.mktemp("interrupt")
    cache = root / "cache"
    _prefill_validation_cache(cache)
    _run(root / "reference", cache)
    return root / "reference", cache


def _interrupted_run(tmp_path: Path, cache: Path, kill_points: list[int]) -> Path:
    out = tmp_path / "run"
    for n, k in enumerate(kill_points):
        at_kill = _kill_after_records(out, cache, k, resume=n > 0)
        _assert_killed_state_is_clean(out, at_kill)
        # a record torn by a kill in the middle of its write: what the atomic writer leaves at worst
        (out / "dataset" / "records" / f".tmp-torn{n}.npz").write_bytes(b"PK\x03\x04 torn")
    _run(out, cache, resume=True)
    return out


def test_killed_mid_round_and_resumed_equals_uninterrupted(reference: tuple[Path, Path], tmp_path: Path) -> None:
    ref, cache = reference
    out = _interrupted_run(tmp_path, cache, [PRETRAIN + 7])  # inside the second round of solves
    _assert_identical_runs(ref, out)
    _assert_the_comparison_detects_a_one_ulp_difference(ref, tmp_path / "copy")


def _assert_the_comparison_detects_a_one_ulp_difference(ref: Path, copy: Path) -> None:
    """Guard against a comparison that cannot fail: one label nudged by one ulp must be caught."""
    shutil.copytree(ref, copy)
    ds = Dataset.open(copy / "dataset")
    record = ds.read(PRETRAIN + 1)
    record.cost_to_go[3] = np.nextafter(record.cost_to_go[3], np.inf)
    ds.record_path(record.index).unlink()
    ds.write(record)
    with pytest.raises(AssertionError, match="cost_to_go"):
        _assert_identical_runs(ref, copy)


@pytest.mark.slow
@pytest.mark.parametrize(
    "kill_points",
    [
        [2],  # inside pretraining (no checkpoint yet)
        [PRETRAIN],  # pretraining solves done: pretraining steps or the first checkpoint under way
        [TOTAL - 1],  # last round
        [4, PRETRAIN + 3, PRETRAIN + 13],  # killed again after each resume
    ],
)
def test_killed_at_other_points_and_resumed_equals_uninterrupted(
    reference: tuple[Path, Path], tmp_path: Path, kill_points: list[int]
) -> None:
    ref, cache = reference
    _assert_identical_runs(ref, _interrupted_run(tmp_path, cache, kill_points))
