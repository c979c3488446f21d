"""Batch solves of many independent trajectory optimizations, in-process, across local processes or on Ray.

Every start's result depends only on ``(task, start, tau, solver_options)``: the optimizer's guess strategy is
deterministic and no warm start carries over from one solve to the next, so the output is identical whatever the
number of workers or the backend. Each worker builds one :class:`TrajectoryOptimizer` per configuration the first
time it needs it and keeps it (a build costs ~1 s; a solve ~10-500 ms), and runs single-threaded (BLAS/OpenMP
threads pinned to 1) so that ``workers`` processes use ``workers`` cores.

The task travels as an object: a registered name is resolved once in the calling process, and the :class:`Task`
itself is pickled to the local workers (with every chunk, ~1 ms) and to the Ray actors (put in the object store once
per call). Nothing is looked up by name on the far side, so a user-defined task or a variant of a built-in one with
the same name is solved as given. A configuration is the task's :meth:`~seagul_envs.tasks.base.Task.fingerprint`
plus the frozen options; a worker checks the fingerprint of the task it received before it builds an optimizer.

Both pools live as long as this process: the local loky pool (idle timeout 300 s) and the Ray actors (created on
the first Ray solve, grown when a later call asks for more workers, rebuilt after ``ray.shutdown()``/``ray.init()``,
killed by :func:`shutdown_ray_pool` or at exit). Training rounds therefore pay the worker start-up and the solver
builds once, not once per round. Each Ray actor holds one CPU of the cluster while the pool lives.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import sys
import threading
from concurrent.futures import FIRST_COMPLETED, Future, wait
from typing import Any

import numpy as np
from cloudpickle import register_pickle_by_value
from joblib.externals.loky import ProcessPoolExecutor
from tqdm.auto import tqdm

from seagul_envs.tasks import file_task_modules, make_task, resolve_task
from seagul_envs.tasks.base import Task
from seagul_learn.results import SolveResult
from seagul_learn.trajopt import TrajectoryOptimizer, TrajOptConfig

_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")

Frozen = tuple[tuple[str, Any], ...]
"""Solver options as a hashable, sorted tuple of ``(name, value)`` pairs (see :func:`_freeze`)."""

# Per-process cache: (task fingerprint, frozen solver options) -> TrajectoryOptimizer.
_OPTIMIZERS: dict[tuple[str, Frozen], Any] = {}


def _freeze(options: dict[str, Any] | None) -> Frozen:
    def norm(v: Any) -> Any:
        if isinstance(v, dict):
            return tuple(sorted((k, norm(x)) for k, x in v.items()))
        if isinstance(v, list):
            return tuple(norm(x) for x in v)
        return v

    return tuple(sorted((k, norm(v)) for k, v in (options or {}).items()))


def _optimizer(task: Task, frozen: Frozen, fingerprint: str | None = None) -> Any:
    """This process's optimizer for ``(task, options)``, built on first use and kept.

    ``fingerprint`` is the task's fingerprint as the caller computed it (None: compute it here). A worker is given it
    with the task, so a cached optimizer is found without hashing the task again; before a build the fingerprint of
    the task that actually arrived is checked against it.
    """
    key = (task.fingerprint() if fingerprint is None else fingerprint, frozen)
    opt = _OPTIMIZERS.get(key)
    if opt is None:
        if fingerprint is not None and task.fingerprint() != fingerprint:
            raise RuntimeError(
                f"task {task.name!r} changed on its way to this worker (fingerprint {task.fingerprint()} here, "
                f"{fingerprint} in the caller): some field of it does not survive pickling"
            )
        options: dict[str, Any] = {
            k: (dict(v) if k == "solver_options" and isinstance(v, tuple) else v) for k, v in frozen
        }
        opt = TrajectoryOptimizer(task, **options).prepare()
        _OPTIMIZERS[key] = opt
    return opt


def _solve_chunk(
    task: Task | str,
    frozen: Frozen,
    starts: np.ndarray,
    taus: np.ndarray,
    fingerprint: str | None = None,
    thetas: np.ndarray | None = None,
) -> list[SolveResult]:
    """Solve one chunk in a worker. ``solve_many`` sends the Task object and its fingerprint; a registered name
    (resolved here, with ``make_task``) is still accepted from direct callers such as the benchmarks. ``thetas``:
    one robot per start (an optimizer built with ``model_params=True``)."""
    if isinstance(task, str):
        task = make_task(task)
    opt = _optimizer(task, frozen, fingerprint)
    if thetas is None:
        return [opt.solve(x, float(t)) for x, t in zip(starts, taus, strict=True)]
    return [opt.solve(x, float(t), theta=th) for x, t, th in zip(starts, taus, thetas, strict=True)]


def _rows(thetas: np.ndarray | None, n: int) -> np.ndarray | None:
    return None if thetas is None else thetas[:n]


def _worker_init() -> None:
    for var in _THREAD_VARS:
        os.environ[var] = "1"


def _chunks(n: int, workers: int, chunk_size: int | None) -> list[np.ndarray]:
    """Index chunks for dynamic scheduling. With ``chunk_size=None``, *guided* sizes: each chunk is a quarter of
    the remaining work per worker, at most 16 and at least 1 solve. Early chunks of 16 amortise the IPC (~1 ms per
    chunk); the shrinking tail keeps the workers finishing together (fixed chunks of 16 left one worker idle for up
    to a whole chunk at the end: 13 chunks on 2 workers is 7 against 6)."""
    w = max(workers, 1)
    out: list[np.ndarray] = []
    start = 0
    while start < n:
        size = chunk_size if chunk_size is not None else max(1, min(16, int(np.ceil((n - start) / (4 * w)))))
        out.append(np.arange(start, min(start + size, n)))
        start += size
    return out


def _check_inputs(
    task: Task, starts: np.ndarray, taus: np.ndarray | None, tail: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    task_name = task.name
    arr = np.asarray(starts, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != task.nx:
        raise ValueError(f"{task_name}: starts must have shape (n, {task.nx}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
        raise ValueError(f"{task_name}: starts contain NaN or inf (rows {bad[:10].tolist()})")
    if taus is None:
        tau_arr = np.full(arr.shape[0], task.tau_nominal)
    else:
        tau_arr = np.asarray(taus, dtype=np.float64).reshape(-1)
        if tau_arr.shape[0] != arr.shape[0]:
            raise ValueError(f"{task_name}: taus must have {arr.shape[0]} entries, got {tau_arr.shape[0]}")
    for t in tau_arr:
        task.check_tau(t, allow_shorter=tail)
    return arr, tau_arr


def _check_thetas(task: Task, thetas: np.ndarray, n: int) -> np.ndarray:
    """``thetas`` as an ``(n, k)`` float array of finite robots, or a ValueError naming the problem."""
    space = task.parameters
    if space is None:
        raise ValueError(f"{task.name}: thetas given, but the task declares no physical parameters (Task.parameters)")
    arr = np.asarray(thetas, dtype=np.float64)
    if arr.ndim != 2 or arr.shape != (n, space.size):
        raise ValueError(f"{task.name}: thetas must have shape ({n}, {space.size}) ({space.names}), got {arr.shape}")
    for row in arr:
        space.check(row, task.name)
    return arr


def _progress(total: int, enabled: bool, desc: str) -> Any:
    return tqdm(total=total, disable=not enabled, desc=desc, unit="solve", smoothing=0.05)


def solve_many(
    task: Task | str,
    starts: np.ndarray,
    taus: np.ndarray | None = None,
    *,
    workers: int = 1,
    backend: str = "local",
    progress: bool = True,
    solver_options: dict | None = None,
    thetas: np.ndarray | None = None,
) -> list[SolveResult]:
    """Solve paper Eq. 1 from every row of ``starts`` and return the results in input order.

    Args:
        task: the :class:`~seagul_envs.tasks.base.Task` to solve, or a registered name (``"acrobot"``,
            ``"glider"``, or one added with ``register_task``), resolved once here with ``make_task``. The object
            itself reaches the workers (by pickling), so a custom task or a variant of a built-in one is solved as
            given; workers cache one optimizer per task fingerprint and options.
        starts: ``(n, nx)`` start states.
        taus: ``(n,)`` times to go (default: the task's nominal for every start).
        workers: processes (``backend="local"``; ``1`` solves in this process) or actors (``backend="ray"``).
        backend: ``"local"`` (process pool on this machine) or ``"ray"`` (needs ``pip install seagul[ray]``; connects to
            ``RAY_ADDRESS`` or ``solver_options["ray_address"]`` if set, else starts a local Ray; the actors are
            reused by later calls, see :func:`shutdown_ray_pool`).
        progress: show a tqdm progress bar.
        solver_options: :class:`~seagul_learn.trajopt.TrajOptConfig` fields (e.g. ``{"solver": "ipopt"}``); the
            key ``"ray_address"`` is read by the Ray backend and not passed on.
        thetas: ``(n, k)`` robots, one per start (``task.parameters.names`` order): every solve takes its robot as
            NLP parameters of one optimizer per worker (``model_params=True`` is implied) and returns
            ``grad_theta`` and ``knot_grad_theta``. None: the task's own robot.

    Returns:
        One :class:`SolveResult` per start; a failed solve has ``success=False`` (never raises for a hard start).

    Raises:
        TypeError: ``task`` is neither a Task nor a str.
        ValueError: an unknown task name or a malformed Task, bad shapes, NaN starts, a ``tau`` outside the task's
            range, unknown backend or options.
    """
    task = resolve_task(task)
    fingerprint = task.fingerprint()
    options = dict(solver_options or {})
    tail = options.get("horizon") is not None
    arr, tau_arr = _check_inputs(task, starts, taus, tail=tail)
    theta_arr = None if thetas is None else _check_thetas(task, thetas, arr.shape[0])
    if theta_arr is not None:
        options["model_params"] = True
    ray_address = options.pop("ray_address", None)
    frozen = _freeze(options)
    n = arr.shape[0]
    if backend not in ("local", "ray"):
        raise ValueError(f"unknown backend {backend!r}; use 'local' or 'ray'")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    # Fail fast (in this process) on bad options rather than inside every worker.
    TrajOptConfig().with_updates(**options).validate()
    if n == 0:
        return []
    if backend == "ray":
        return _solve_ray(task, fingerprint, frozen, arr, tau_arr, workers, progress, ray_address, theta_arr)
    if workers == 1:
        opt = _optimizer(task, frozen, fingerprint)
        out: list[SolveResult] = []
        with _progress(n, progress, f"{task.name} solves") as bar:
            for i, (x, t) in enumerate(zip(arr, tau_arr, strict=True)):
                out.append(opt.solve(x, float(t), theta=None if theta_arr is None else theta_arr[i]))
                bar.update(1)
        return out
    return _solve_local(task, fingerprint, frozen, arr, tau_arr, workers, progress, theta_arr)


_POOL: dict[str, Any] = {}


def _local_pool(workers: int) -> Any:
    """This module's own loky pool of ``workers`` processes, kept alive between calls (idle timeout 300 s).

    loky: spawned (not forked) workers that need no ``if __name__ == "__main__"`` guard in the caller's script, and
    each worker's cached optimizer is reused by the next batch. A private executor, not loky's process-wide reusable
    one: joblib's ``Parallel`` (used by callers, e.g. the closed-loop evaluation) takes over that singleton and fails
    on one it did not create.
    """
    pool = _POOL.get("pool")
    if pool is not None and (_POOL.get("workers") != workers or pool._flags.broken or pool._flags.shutdown):
        pool.shutdown(wait=False)
        pool = None
    if pool is None:
        env = {v: "1" for v in _THREAD_VARS}
        pool = ProcessPoolExecutor(max_workers=workers, timeout=300, initializer=_worker_init, env=env)
        _POOL.update(pool=pool, workers=workers)
    return pool


def _solve_local(
    task: Task,
    fingerprint: str,
    frozen: Frozen,
    starts: np.ndarray,
    taus: np.ndarray,
    workers: int,
    progress: bool,
    thetas: np.ndarray | None = None,
) -> list[SolveResult]:
    n = starts.shape[0]
    chunks = _chunks(n, workers, None)
    results: list[SolveResult | None] = [None] * n
    pool = _local_pool(workers)
    # A module that load_task read from a file after the pool's workers started is on no worker's sys.path (a worker
    # inherits the path at its start, and the pool outlives calls): its classes and functions travel by value, as
    # on Ray (loky pickles with cloudpickle, as the closed-loop evaluation's workers do).
    for module in file_task_modules():
        register_pickle_by_value(module)
    with _progress(n, progress, f"{task.name} solves x{workers}") as bar:
        pending: dict[Future[list[SolveResult]], np.ndarray] = {}
        queue = list(chunks)
        # Bounded submission keeps memory flat for very large batches.
        limit = 4 * workers

        def submit_more() -> None:
            while queue and len(pending) < limit:
                idx = queue.pop(0)
                rows = None if thetas is None else thetas[idx]
                fut = pool.submit(_solve_chunk, task, frozen, starts[idx], taus[idx], fingerprint, rows)
                pending[fut] = idx

        submit_more()
        while pending:
            done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
            for fut in done:
                idx = pending.pop(fut)
                for i, res in zip(idx, fut.result(), strict=True):
                    results[int(i)] = res
                bar.update(len(idx))
            submit_more()
    return [r for r in results if r is not None]


class _RayPool:
    """This process's Ray actors, created on the first Ray solve and reused by every later one.

    ``key`` names the Ray session the actors live in (process id, GCS address, session name, job id): after
    ``ray.shutdown()`` and a new ``ray.init()`` (or a fork) the key no longer matches, the stale handles are dropped
    and a new pool is built. ``created`` counts actor creations and ``retried`` the chunks re-run after an actor's
    process died, both over the process's life (tests assert on them).
    """

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.key: tuple[Any, ...] | None = None
        self.actors: list[Any] = []
        self.created = 0
        self.retried = 0
        """Chunks served first by an actor that Ray restarted after its process died. ``_solve_ray`` keeps one chunk
        in flight per actor, so inside a call this is the chunk the dead process was solving, re-run from its inputs
        (an actor that died idle, between two calls, counts its next call's first chunk)."""

    def clear(self) -> list[Any]:
        actors, self.actors, self.key = self.actors, [], None
        return actors


_RAY_POOL = _RayPool()


def _ray_session_key(ray: Any) -> tuple[Any, ...]:
    ctx = ray.get_runtime_context()
    return (os.getpid(), ctx.gcs_address, ctx.get_session_name(), ctx.get_job_id())


def _ray_init(ray: Any, workers: int, address: str | None) -> None:
    if ray.is_initialized():
        return
    address = address or os.environ.get("RAY_ADDRESS")
    env = {"env_vars": {v: "1" for v in _THREAD_VARS}}
    if address:
        ray.init(address=address, runtime_env=env, ignore_reinit_error=True, log_to_driver=False)
    else:
        # Room for a later, larger call to grow the pool up to this machine's cores (or ``workers`` if more).
        # ``address="local"``: a private instance even when another Ray runs on this machine (``ray.init()`` without
        # an address would join the latest one in /tmp/ray/ray_current_cluster, and refuses ``num_cpus`` there).
        cpus = max(workers, os.cpu_count() or 1)
        ray.init(address="local", num_cpus=cpus, runtime_env=env, ignore_reinit_error=True, log_to_driver=False)


def _ray_actors(ray: Any, n: int) -> list[Any]:
    """The first ``n`` actors of this process's pool, creating the pool (or growing it) as needed."""
    with _RAY_POOL.lock:
        key = _ray_session_key(ray)
        if _RAY_POOL.key != key:
            _RAY_POOL.clear()  # actors of a Ray session that is gone (they died with it): only forget them
            _RAY_POOL.key = key
        if len(_RAY_POOL.actors) < n:
            actor_cls = _ray_actor_class(ray)
            while len(_RAY_POOL.actors) < n:
                _RAY_POOL.actors.append(actor_cls.remote())
                _RAY_POOL.created += 1
        return _RAY_POOL.actors[:n]


def shutdown_ray_pool() -> None:
    """Kill this process's Ray solver actors (freeing their CPUs); the next Ray solve builds a new pool.

    Registered with :mod:`atexit`; safe to call at any time, also when Ray is not installed, not initialised or
    already shut down.
    """
    with _RAY_POOL.lock:
        key, actors = _RAY_POOL.key, _RAY_POOL.clear()
    if not actors:
        return
    ray = sys.modules.get("ray")
    if ray is None or not ray.is_initialized():
        return
    with contextlib.suppress(Exception):
        if _ray_session_key(ray) != key:
            return
    for a in actors:
        with contextlib.suppress(Exception):
            ray.kill(a)


atexit.register(shutdown_ray_pool)


def _solve_ray(
    task: Task,
    fingerprint: str,
    frozen: Frozen,
    starts: np.ndarray,
    taus: np.ndarray,
    workers: int,
    progress: bool,
    address: str | None,
    thetas: np.ndarray | None = None,
) -> list[SolveResult]:
    try:  # an optional dependency (the ray extra): imported only for backend='ray'
        import ray
    except ImportError as err:
        raise ImportError(
            "backend='ray' needs the optional Ray extra: pip install 'seagul[ray]' (or pip install ray)"
        ) from err
    _ray_init(ray, workers, address)

    n = starts.shape[0]
    chunks = _chunks(n, workers, None)
    actors = _ray_actors(ray, min(workers, len(chunks)))
    results: list[SolveResult | None] = [None] * n
    queue = list(chunks)
    in_flight: dict[Any, tuple[int, np.ndarray]] = {}
    # A module that load_task read from a file (``--task path/file.py:factory``) is on no Ray worker's path: its
    # classes and functions in the task (e.g. the parameter dataclass) travel by value.
    for module in file_task_modules():
        ray.cloudpickle.register_pickle_by_value(module)
    task_ref = ray.put(task)  # serialised once per call; Ray hands the actors the Task itself

    def submit(actor_i: int) -> None:
        if queue:
            idx = queue.pop(0)
            rows = None if thetas is None else thetas[idx]
            ref = actors[actor_i].run_chunk.remote(task_ref, frozen, starts[idx], taus[idx], fingerprint, rows)
            in_flight[ref] = (actor_i, idx)

    finished = False
    try:
        with _progress(n, progress, f"{task.name} solves (ray x{len(actors)})") as bar:
            for i in range(len(actors)):
                submit(i)
            while in_flight:
                ready, _ = ray.wait(list(in_flight), num_returns=1)
                ref = ready[0]
                actor_i, idx = in_flight.pop(ref)
                chunk, rerun = ray.get(ref)
                if rerun:
                    with _RAY_POOL.lock:
                        _RAY_POOL.retried += 1
                for i, res in zip(idx, chunk, strict=True):
                    results[int(i)] = res
                bar.update(len(idx))
                submit(actor_i)
        finished = True
    finally:
        if not finished:
            # An error or an interrupt: chunks may still be queued on the actors, or an actor may be dead for good.
            # Kill the pool so that the next call starts from clean actors instead of waiting behind stale work.
            shutdown_ray_pool()
    return [r for r in results if r is not None]


_RAY_ACTOR: Any = None


def _ray_actor_class(ray: Any) -> Any:
    """A pool actor: any task and options (each built solver cached in the actor's process while it lives, keyed by
    the task's fingerprint and the options).

    A dead actor is restarted (its solvers are rebuilt on demand) and its in-flight chunk re-run (deterministic, so
    safe). ``run_chunk`` (what :func:`solve_many` calls) tells the caller whether the chunk is the first one a
    restarted actor serves, which :attr:`_RayPool.retried` counts; ``solve_chunk`` returns the results alone (the
    benchmarks call it directly).

    Test hook: :meth:`exit_at_solve` arms the actor to end its own process (``os._exit(1)``, as a crash inside the
    solver would) when it starts its ``k``-th solve from then on, in the middle of a chunk. The arming lives in the
    actor's process, so the restarted actor is unarmed and the re-run chunk completes: a test injects a worker death
    at a chosen solve, and checks the recovery by counters, without racing a kill from outside against the solves.
    """
    global _RAY_ACTOR
    if _RAY_ACTOR is None:

        class _SolverActor:
            def __init__(self) -> None:
                _worker_init()
                self.restarted = bool(ray.get_runtime_context().was_current_actor_reconstructed)
                """This process replaces one of the same actor that died (Ray restarted the actor)."""
                self.chunks = 0
                self.exit_in: int | None = None

            def solve_chunk(
                self,
                task: Task | str,
                frozen: Frozen,
                starts: np.ndarray,
                taus: np.ndarray,
                fingerprint: str | None = None,
                thetas: np.ndarray | None = None,
            ) -> list[SolveResult]:
                self.chunks += 1
                if self.exit_in is not None and self.exit_in <= len(starts):
                    done = self.exit_in - 1  # solve the ones before, then die inside the chunk
                    if done:
                        _solve_chunk(task, frozen, starts[:done], taus[:done], fingerprint, _rows(thetas, done))
                    os._exit(1)
                if self.exit_in is not None:
                    self.exit_in -= len(starts)
                return _solve_chunk(task, frozen, starts, taus, fingerprint, thetas)

            def run_chunk(
                self,
                task: Task | str,
                frozen: Frozen,
                starts: np.ndarray,
                taus: np.ndarray,
                fingerprint: str | None = None,
                thetas: np.ndarray | None = None,
            ) -> tuple[list[SolveResult], bool]:
                """``solve_chunk``'s results and whether this is a restarted actor's first chunk (a re-run one)."""
                rerun = self.restarted and self.chunks == 0
                return self.solve_chunk(task, frozen, starts, taus, fingerprint, thetas), rerun

            def exit_at_solve(self, k: int) -> None:
                """Test hook: end this actor's process when it starts its ``k``-th solve from now (``k >= 1``)."""
                if k < 1:
                    raise ValueError(f"k must be >= 1, got {k}")
                self.exit_in = int(k)

            def pid(self) -> int:
                return os.getpid()

            def node_id(self) -> str:
                return ray.get_runtime_context().get_node_id()

        _RAY_ACTOR = ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=3)(_SolverActor)
    return _RAY_ACTOR


__all__ = ["shutdown_ray_pool", "solve_many"]
