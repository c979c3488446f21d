"""The Ray backend of ``solve_many``: bit-identical to the local backend, and a worker that dies mid-solve is retried.

Needs the optional extra: ``pip install 'seagul[ray]'``; skipped without it. A local Ray with two
CPUs stands in for a cluster. ``seagul_learn.parallel`` runs one ``_SolverActor`` per worker, declared with
``max_restarts=-1, max_task_retries=3``: when an actor's process dies, Ray restarts the actor and re-runs the chunk
that was in flight (safe: a chunk's results depend only on its inputs). The fault is injected inside the actor, with
its test hook ``exit_at_solve(k)``: the actor ends its own process (``os._exit(1)``) when it starts its k-th solve,
at a point fixed in advance and not raced against the solves. The recovery is asserted by counters (one re-run chunk
per death in ``_RAY_POOL.retried``, no new actor in ``_RAY_POOL.created``, a new pid for each dead actor only) and by
the results: every start's exactly once, equal bit for bit to the local backend's. With the retry options switched
off the same fault must lose the chunk (so the test can fail).

The actors form one pool per process, created on the first Ray solve and reused by later calls
(grown when a call asks for more workers, rebuilt after a new ``ray.init``); the tests count actor creations and
compare actor ids and pids across calls, and a two-node cluster simulated with ``ray.cluster_utils.Cluster`` checks
that the pool spreads over both nodes with results equal to the local backend's.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from result_checks import assert_same_results

from seagul_envs import make_task
from seagul_learn import parallel
from seagul_learn.parallel import solve_many
from seagul_learn.results import SolveResult

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.ray


@pytest.fixture(scope="module", autouse=True)
def _private_ray() -> Iterator[None]:
    """Never an outside cluster named by RAY_ADDRESS; Ray (and our actor pool) shut down after the module."""
    if ray.is_initialized():
        ray.shutdown()
    address = os.environ.pop("RAY_ADDRESS", None)
    try:
        yield
    finally:
        parallel.shutdown_ray_pool()
        ray.shutdown()
        if address is not None:
            os.environ["RAY_ADDRESS"] = address


_LOCAL_GCS: dict[str, str] = {}


@pytest.fixture
def local_ray() -> Any:
    """A private local Ray instance with two CPUs, started once per module (again after the cluster test)."""
    if ray.is_initialized() and ray.get_runtime_context().gcs_address != _LOCAL_GCS.get("gcs"):
        ray.shutdown()
    if not ray.is_initialized():
        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
        _LOCAL_GCS["gcs"] = ray.get_runtime_context().gcs_address
    return ray


FAST: dict[str, Any] = {"codegen": False, "horizon": 10, "plan": ("ipopt:line",), "multi_start": "never"}
"""The robots' and the fault tests' solves: one interpreted IPOPT attempt on the acrobot's 1 s tail (10 intervals),
~50 ms each and nothing compiled, so a restarted actor is back within its process start; what is tested is the
plumbing (each start's robot, the pool's recovery), not the swing-up."""


def _acrobot_starts(n: int) -> np.ndarray:
    return make_task("acrobot").sample_x0(np.random.default_rng(0), n)


@pytest.mark.parametrize("task_name", ["acrobot", "glider"])
def test_ray_backend_equals_local_backend(local_ray: Any, task_name: str) -> None:
    task = make_task(task_name)
    starts = task.sample_x0(np.random.default_rng(1), 5)
    lo, hi = task.tau_range
    taus = np.linspace(lo, hi, 5)  # the glider's free final time over T0; the acrobot's T0 is one value
    # The local backend's worker processes, like Ray's actors, start fresh with one BLAS thread; an in-process solve
    # runs with whatever the calling process has loaded (here: the pytest worker after other test files), and near a
    # tie between two attempts' values that can pick the other attempt.
    local = solve_many(task_name, starts, taus, workers=2, progress=False)
    remote = solve_many(task_name, starts, taus, workers=2, backend="ray", progress=False)
    assert sum(r.success for r in local) >= 3
    assert_same_results(local, remote)


def test_ray_solves_each_start_for_its_robot_like_the_local_backend(local_ray: Any) -> None:
    task = make_task("acrobot")
    rng = np.random.default_rng(2)
    starts = task.sample_x0(rng, 3)
    thetas = task.parameters.sample(rng, 3)
    taus = np.full(3, 1.0)  # FAST's 1 s tails: the robots' plumbing is tested, not the swing-up
    local = solve_many(task, starts, taus, thetas=thetas, workers=1, progress=False, solver_options=FAST)
    remote = solve_many(
        task, starts, taus, thetas=thetas, workers=2, backend="ray", progress=False, solver_options=FAST
    )
    assert_same_results(local, remote)
    nominal = solve_many(task, starts[:1], taus[:1], workers=1, progress=False, solver_options=FAST)[0]
    assert local[0].success and nominal.success and abs(local[0].value - nominal.value) > 1e-6  # theta was used
    for a, b, theta in zip(local, remote, thetas, strict=True):
        np.testing.assert_array_equal(b.theta, theta)
        np.testing.assert_array_equal(a.knot_grad_theta, b.knot_grad_theta)


def _arm(faults: dict[int, int]) -> None:
    """Arm pool actor ``i`` to end its own process at its ``k``-th solve from now, for each ``i: k`` of ``faults``."""
    ray.get([parallel._RAY_POOL.actors[i].exit_at_solve.remote(k) for i, k in faults.items()])


def _pids() -> list[int]:
    return ray.get([a.pid.remote() for a in parallel._RAY_POOL.actors])


def _fast(starts: np.ndarray, workers: int, backend: str = "ray") -> list[SolveResult]:
    taus = np.full(starts.shape[0], 1.0)
    return solve_many("acrobot", starts, taus, workers=workers, backend=backend, progress=False, solver_options=FAST)


def _assert_each_start_once(starts: np.ndarray, results: list[SolveResult]) -> None:
    """One result per start, in input order: no chunk lost, none delivered twice."""
    assert len(results) == starts.shape[0]
    for i, (x, res) in enumerate(zip(starts, results, strict=True)):
        np.testing.assert_array_equal(res.x_init, x, err_msg=f"result {i} is not start {i}'s")


@pytest.mark.parametrize(
    ("workers", "faults"),
    [
        # One actor, guided chunks of 2, 2, 1, 1, 1, 1 starts: it dies after the first solve of its first chunk.
        (1, {0: 2}),
        # Two actors; each call hands each actor one chunk first, so both die on their first chunk of the call.
        # Two actor restarts cost ~45 s on a loaded 2-core machine: slow, the mid-chunk case covers the contract.
        pytest.param(2, {0: 1, 1: 1}, marks=pytest.mark.slow),
    ],
    ids=["mid-chunk", "both-actors"],
)
def test_an_actor_that_dies_mid_solve_is_restarted_and_its_chunk_rerun(
    local_ray: Any, workers: int, faults: dict[int, int]
) -> None:
    starts = _acrobot_starts(8)
    local = _fast(starts, workers=1, backend="local")
    first = _fast(starts, workers)  # the pool has (at least) ``workers`` actors from here on
    assert_same_results(local, first)
    created, retried, pids = parallel._RAY_POOL.created, parallel._RAY_POOL.retried, _pids()[:workers]
    with pytest.raises(ray.exceptions.RayTaskError, match="k must be >= 1"):
        _arm({0: 0})

    _arm(faults)
    remote = _fast(starts, workers)

    assert parallel._RAY_POOL.retried == retried + len(faults)  # the chunk each dead process held, run again
    assert parallel._RAY_POOL.created == created  # Ray restarted the same actors; the pool made none
    after = _pids()[:workers]
    for i, (old, new) in enumerate(zip(pids, after, strict=True)):
        assert (new != old) == (i in faults), f"actor {i}: pid {old} -> {new}"
    _assert_each_start_once(starts, remote)
    assert_same_results(local, remote)
    # The restarted actors are unarmed: the next call has nothing to re-run.
    again = _fast(starts, workers)
    assert parallel._RAY_POOL.retried == retried + len(faults) and _pids()[:workers] == after
    assert_same_results(local, again)


def test_without_the_retry_options_the_same_fault_loses_the_chunk(
    local_ray: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Guard: the test above would fail if ``parallel`` stopped restarting actors and retrying their tasks."""
    real = parallel._ray_actor_class(ray)

    class NoRetry:
        @staticmethod
        def remote(*args: Any) -> Any:
            return real.options(max_restarts=0, max_task_retries=0).remote(*args)

    monkeypatch.setattr(parallel, "_ray_actor_class", lambda _ray: NoRetry)
    parallel.shutdown_ray_pool()  # the pool's actors (with retries) would otherwise be reused
    starts = _acrobot_starts(8)
    _fast(starts, workers=2)  # a pool of actors without retries
    retried = parallel._RAY_POOL.retried
    _arm({0: 1})
    with pytest.raises(ray.exceptions.RayActorError):
        _fast(starts, workers=2)
    assert parallel._RAY_POOL.retried == retried
    assert parallel._RAY_POOL.actors == []  # a failed call drops the pool: the next one starts from fresh actors


def test_training_on_ray_equals_training_in_process(local_ray: Any, tmp_path: Path) -> None:
    """The same job (``seagul train --backend ray``): identical dataset and weights to the in-process run."""
    from seagul_learn.training import AdversarialOptions, RuntimeConfig, ScheduleConfig, TrainConfig, train

    def run(name: str, **runtime: Any) -> Any:
        config = TrainConfig(
            task="acrobot",
            sampler=AdversarialOptions(max_steps=2),
            budget=2,  # the actors (and their solvers) are built once, on the first Ray call
            schedule=ScheduleConfig(
                solves_per_round=2, train_steps_per_round=10, batch_size=32, pretrain_solves=2, pretrain_steps=5
            ),
            seed=7,
            validate=False,
            runtime=RuntimeConfig(progress=False, **runtime),
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


def _pool_ids() -> list[str]:
    return [a._actor_id.hex() for a in parallel._RAY_POOL.actors]


def _gcs_solver_actors() -> set[str] | None:
    """Ids of every ``_SolverActor`` ever created in this Ray session (alive or dead), as the GCS records them.

    Through the state API when it is available (it needs the dashboard), else the GCS actor table that backs it;
    None when neither answers (the pool's own bookkeeping is checked anyway).
    """
    try:
        from ray.util.state import list_actors

        return {a.actor_id for a in list_actors(limit=10_000) if a.class_name.endswith("_SolverActor")}
    except Exception:
        pass
    try:
        from ray._private import state

        table = state.actors()
    except Exception:
        return None
    return {k for k, v in table.items() if str(v.get("ActorClassName", "")).endswith("_SolverActor")}


def test_later_calls_reuse_the_actor_pool(local_ray: Any) -> None:
    starts = _acrobot_starts(6)
    local = _fast(starts, workers=1, backend="local")  # the pool's plumbing is tested, not the swing-up (FAST)
    parallel.shutdown_ray_pool()  # start without a pool: the first call creates it
    created = parallel._RAY_POOL.created

    first = _fast(starts, workers=1)
    assert parallel._RAY_POOL.created == created + 1
    (id0,) = _pool_ids()
    (pid0,) = ray.get([a.pid.remote() for a in parallel._RAY_POOL.actors])

    second = _fast(starts, workers=2)  # grows the pool by one
    assert parallel._RAY_POOL.created == created + 2
    ids = _pool_ids()
    assert len(ids) == 2 and ids[0] == id0
    pids = ray.get([a.pid.remote() for a in parallel._RAY_POOL.actors])
    assert pids[0] == pid0 and pids[1] != pid0
    in_gcs = _gcs_solver_actors()
    if in_gcs is not None:
        assert set(ids) <= in_gcs

    third = _fast(starts[::-1], workers=2)
    assert parallel._RAY_POOL.created == created + 2, "the third call created actors"
    assert _pool_ids() == ids
    assert ray.get([a.pid.remote() for a in parallel._RAY_POOL.actors]) == pids  # the same processes
    if in_gcs is not None:
        assert _gcs_solver_actors() == in_gcs, "Ray recorded new actors during the third call"

    assert_same_results(local, first)
    assert_same_results(local, second)
    assert_same_results(local[::-1], third)

    handles = list(parallel._RAY_POOL.actors)
    parallel.shutdown_ray_pool()
    assert parallel._RAY_POOL.actors == []
    # ray.kill is asynchronous: a call submitted right after it may still be served, so poll until the actor is gone.
    deadline = time.monotonic() + 60
    with pytest.raises(ray.exceptions.RayActorError):
        while time.monotonic() < deadline:
            ray.get(handles[0].pid.remote(), timeout=60)
            time.sleep(0.2)


@pytest.mark.slow  # ~30 s of starting a second Ray node; the backend's results are checked by the local tests above
def test_two_node_cluster_spreads_the_pool_over_both_nodes() -> None:
    """Head + one worker node, 1 CPU each, on this machine: two actors must land one per node."""
    from ray.cluster_utils import Cluster

    starts = _acrobot_starts(6)
    local = solve_many("acrobot", starts, workers=1, progress=False)
    if ray.is_initialized():
        ray.shutdown()  # the module's local Ray: the pool made there is now stale
    stale = _pool_ids()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, log_to_driver=False)
        created = parallel._RAY_POOL.created
        remote = solve_many("acrobot", starts, workers=2, backend="ray", progress=False)
        assert parallel._RAY_POOL.created == created + 2  # a fresh pool on the new cluster
        assert not set(_pool_ids()) & set(stale)
        assert_same_results(local, remote)
        nodes = set(ray.get([a.node_id.remote() for a in parallel._RAY_POOL.actors]))
        alive_nodes = {n["NodeID"] for n in ray.nodes() if n["Alive"]}
        assert len(alive_nodes) == 2
        assert nodes == alive_nodes, "the two actors did not run on both nodes"
        again = solve_many("acrobot", starts, workers=2, backend="ray", progress=False)
        assert parallel._RAY_POOL.created == created + 2
        assert_same_results(local, again)
        # Without an address the backend starts its own Ray, even with this cluster the latest on the machine
        # (plain ``ray.init(num_cpus=...)`` would try to join it and refuse the CPU count).
        parallel.shutdown_ray_pool()
        ray.shutdown()
        parallel._ray_init(ray, 1, None)
        assert ray.get_runtime_context().gcs_address != cluster.address
    finally:
        parallel.shutdown_ray_pool()
        ray.shutdown()
        cluster.shutdown()
