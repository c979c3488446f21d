"""The Ray backend of ``solve_many``: bit-identical to the local backend, and a worker killed mid-solve is retried.

Issue 7 item 5 (needs the optional extra: ``pip install 'seagul[ray]'``; skipped without it). A local Ray with two
CPUs stands in for a cluster. ``seagul_learn.parallel`` runs one ``_SolverActor`` per worker, declared with
``max_restarts=-1, max_task_retries=3``: when an actor's process dies, Ray restarts the actor and re-runs the chunk
that was in flight (safe: a chunk's results depend only on its inputs). The test SIGKILLs an actor process while
it executes ``solve_chunk`` (Ray names the process ``ray::_SolverActor.solve_chunk`` then) and checks that every
result still comes back, equal bit for bit to the local backend's; with the retry options switched off the same
kill must lose the chunk (so the test can fail).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from seagul_envs import make_task
from seagul_learn import parallel
from seagul_learn.parallel import solve_many
from seagul_learn.results import SolveResult

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.ray

_SOLVING = b"ray::_SolverActor.solve_chunk"


@pytest.fixture(scope="module")
def local_ray() -> Iterator[Any]:
    """A private local Ray instance with two CPUs (never an outside cluster named by RAY_ADDRESS)."""
    if ray.is_initialized():
        ray.shutdown()
    address = os.environ.pop("RAY_ADDRESS", None)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()
        if address is not None:
            os.environ["RAY_ADDRESS"] = address


def _assert_same_results(a: list[SolveResult], b: list[SolveResult]) -> None:
    assert len(a) == len(b)
    for i, (ra, rb) in enumerate(zip(a, b, strict=True)):
        for f in fields(SolveResult):
            if f.name == "solve_time":
                continue
            va, vb = getattr(ra, f.name), getattr(rb, f.name)
            if isinstance(va, np.ndarray | float):
                np.testing.assert_array_equal(va, vb, err_msg=f"result {i}: {f.name}")
            else:
                assert va == vb, f"result {i}: {f.name}: {va!r} != {vb!r}"


def _acrobot_starts(n: int) -> np.ndarray:
    return make_task("acrobot").sample_x0(np.random.default_rng(0), n)


@pytest.mark.parametrize("task_name", ["acrobot", "glider"])
def test_ray_backend_equals_local_backend(local_ray: Any, task_name: str) -> None:
    task = make_task(task_name)
    starts = task.sample_x0(np.random.default_rng(1), 5)
    lo, hi = task.tau_range
    taus = np.linspace(lo, hi, 5)  # the glider's free final time over T0; the acrobot's T0 is one value
    local = solve_many(task_name, starts, taus, workers=1, progress=False)
    remote = solve_many(task_name, starts, taus, workers=2, backend="ray", progress=False)
    assert sum(r.success for r in local) >= 3
    _assert_same_results(local, remote)


def _parent(pid: int) -> int:
    stat = Path(f"/proc/{pid}/stat").read_text()
    return int(stat[stat.rindex(")") + 2 :].split()[1])  # the command name may contain spaces


def _descends_from(pid: int, ancestor: int) -> bool:
    """True if ``pid`` is a (grand)child of ``ancestor``: only our own Ray's workers may be killed."""
    while pid > 1:
        if pid == ancestor:
            return True
        pid = _parent(pid)
    return False


class _ActorKiller(threading.Thread):
    """SIGKILLs the first actor process of THIS test's Ray (a descendant of this process) executing ``solve_chunk``."""

    def __init__(self, timeout: float = 120.0) -> None:
        super().__init__(daemon=True)
        self.timeout = timeout
        self.killed_pid: int | None = None
        self.stop = threading.Event()

    def run(self) -> None:
        deadline = time.monotonic() + self.timeout
        while not self.stop.is_set() and time.monotonic() < deadline:
            for entry in os.listdir("/proc"):
                if not entry.isdigit():
                    continue
                try:
                    mine = Path(f"/proc/{entry}/cmdline").read_bytes().startswith(_SOLVING)
                    mine = mine and _descends_from(int(entry), os.getpid())
                except (OSError, ValueError):  # the process ended while we looked
                    continue
                if mine:
                    os.kill(int(entry), signal.SIGKILL)
                    self.killed_pid = int(entry)
                    return
            time.sleep(0.005)


def _solve_while_killing(starts: np.ndarray) -> tuple[list[SolveResult], _ActorKiller]:
    killer = _ActorKiller()
    killer.start()
    try:
        results = solve_many("acrobot", starts, workers=2, backend="ray", progress=False)
    finally:
        killer.stop.set()
        killer.join()
    return results, killer


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="finds the actor process through /proc")
def test_actor_killed_mid_solve_is_retried_not_lost(local_ray: Any) -> None:
    starts = _acrobot_starts(8)  # one start per chunk here, so the kill lands inside a solve
    local = solve_many("acrobot", starts, workers=1, progress=False)
    remote, killer = _solve_while_killing(starts)
    assert killer.killed_pid is not None, "no actor was seen solving: the kill did not happen"
    _assert_same_results(local, remote)


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="finds the actor process through /proc")
def test_without_the_retry_options_the_same_kill_loses_the_chunk(
    local_ray: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Guard: the test above would fail if ``parallel`` stopped restarting actors and retrying their tasks."""
    real = parallel._ray_actor_class(ray)

    class NoRetry:
        @staticmethod
        def remote(*args: Any) -> Any:
            return real.options(max_restarts=0, max_task_retries=0).remote(*args)

    monkeypatch.setattr(parallel, "_ray_actor_class", lambda _ray: NoRetry)
    with pytest.raises(ray.exceptions.RayActorError):
        _solve_while_killing(_acrobot_starts(8))


def test_training_on_ray_equals_training_in_process(local_ray: Any, tmp_path: Path) -> None:
    """The same job (``seagul train --backend ray``): identical dataset and weights to the in-process run."""
    from seagul_learn.training import TrainConfig, train

    def run(name: str, **runtime: Any) -> Any:
        config = TrainConfig(
            task="acrobot",
            sampler="adversarial",
            budget=2,  # each batch call starts fresh actors (~3 s here): keep the calls few
            solves_per_round=2,
            train_steps_per_round=10,
            batch_size=32,
            pretrain_solves=2,
            pretrain_steps=5,
            adv_max_steps=2,
            seed=7,
            validate=False,
            progress=False,
            **runtime,
        )
        return train(config, tmp_path / name)

    local, remote = run("local"), run("ray", backend="ray", workers=2)
    recs_local, recs_remote = local.dataset.records(), remote.dataset.records()
    assert len(recs_local) == len(recs_remote) == 2 + 2
    assert any(r.step > 0 for r in recs_local)  # an ascent iterate: a start chosen by the trained network
    for a, b in zip(recs_local, recs_remote, strict=True):
        arrays_a, arrays_b = a.to_arrays(), b.to_arrays()
        for key in arrays_a.keys() - {"solve_time"}:
            np.testing.assert_array_equal(arrays_a[key], arrays_b[key], err_msg=f"record {a.index}: {key}")
    np.testing.assert_array_equal(local.network.casadi_parameters(), remote.network.casadi_parameters())
