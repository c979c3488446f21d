"""How learning code asks for solves: an injected batch solver, wrapped by a runner that numbers and stores them.

A *batch solver* is any callable ``(starts (n, nx), taus (n,)) -> list[SolveResult]`` in input order (the real
one is :func:`trajopt_batch_solver`, built on ``seagul_learn.parallel.solve_many``; tests inject a toy with a known
value function). Runs over robots (``TrainConfig.model_params``) call it as ``(starts, taus, thetas (n, k))``: each
solve for its own physical parameters, taken as NLP parameters by one built optimizer.

:class:`SolveRunner` gives every requested solve the next deterministic index, reuses the record already on disk
for that index (an interrupted run resumes without re-solving or duplicating), writes each new record atomically as
soon as its chunk finishes, and counts solves and failures.
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

import seagul_control.transcription
import seagul_envs.tasks.acrobot
import seagul_envs.tasks.base
import seagul_envs.tasks.glider
import seagul_envs.tasks.profile
import seagul_learn.trajopt
from seagul_control._io import atomic_write_bytes
from seagul_envs.tasks import resolve_task
from seagul_envs.tasks.base import Task
from seagul_learn.dataset import Dataset, DatasetError, SolveRecord
from seagul_learn.parallel import solve_many
from seagul_learn.results import SolveResult

BatchSolver = Callable[..., list[SolveResult]]
"""``(starts (n, nx), taus (n,)[, thetas (n, k)]) -> list[SolveResult]`` in input order; never raises for an
infeasible start. ``thetas`` (the robots' physical parameters, ``task.parameters.names`` order) is passed only by
runs over robots; a solver that takes it returns ``SolveResult.theta``/``grad_theta``/``knot_grad_theta``."""


TAIL_SOLVER_DEFAULTS: dict[str, Any] = {
    "plan": ("ipopt_fast:line", "ipopt:line", "ipopt:goal"),
    "multi_start": "never",
    "max_iter": 150,
    "solver_options": {"ipopt.max_wall_time": 20.0},
}
"""Optimizer options of tail problems unless the caller sets them. Tails from the MPC's planned terminal states are
far off the data: 1-2 s per solve with the multi-start's extra attempts (half without), and a fallback IPOPT attempt
at 500 iterations once took minutes. No multi-start (a poor local optimum only *over*-estimates ``V`` there, the
direction that keeps the planner away), at most 150 iterations and 20 s per attempt, and IPOPT only: fatrop, the
first attempt of a full solve, looped without end inside its search-direction computation on two tails of the
closed-loop benchmark (minutes without returning; max_iter does not bound that loop), IPOPT has a wall-time limit.
A failed tail is recorded, counted and never trained on."""


def tail_horizon(task: Task, tau: float) -> int | None:
    """Intervals of the tail problem from time to go ``tau``, or None when ``tau`` is a full-horizon time to go.

    The full problem has ``m`` intervals for ``tau`` in T0 (nominal step ``h = tau_nominal / m``). A state reached
    with less time to go (the MPC's planned terminal state, a mid-trajectory knot) starts the *tail* problem with
    ``k = round(tau / h)`` intervals (Bellman's principle: its optimal cost is ``V(x, tau)``): of exactly ``h`` for a
    fixed-step task, free steps in the task's step bounds with ``sum(h_k) = tau`` for a free-time task.

    Raises:
        ValueError: ``tau`` is above T0, not a multiple of the step (fixed-step tasks), or not reachable with ``k``
            steps inside the step bounds (free-time tasks).
    """
    lo, hi = task.tau_range
    if lo - 1e-9 <= tau <= hi + 1e-9:
        return None
    h = task.tau_nominal / task.num_steps
    k = round(tau / h)
    if not (1 <= k < task.num_steps) or tau > hi:
        raise ValueError(f"{task.name}: time to go {tau} s is not a tail of the full problem (0 < tau < {lo} s)")
    if task.fixed_step and abs(k * h - tau) > 1e-6:
        raise ValueError(f"{task.name}: time to go {tau} s is not a tail of the full problem (a multiple of {h} s)")
    step_lo, step_hi = task.step_bounds
    if not task.fixed_step and not (k * step_lo - 1e-9 <= tau <= k * step_hi + 1e-9):
        raise ValueError(f"{task.name}: time to go {tau} s is not reachable with {k} steps in {task.step_bounds} s")
    return int(k)


class TrajoptBatchSolver:
    """The real batch solver of one task (built by :func:`trajopt_batch_solver`; a :data:`BatchSolver`).

    Attributes:
        task: the task it solves (resolved once, in the process that built the solver). :class:`CachedBatchSolver`
            reads it to key its cache by the task's content.
    """

    def __init__(
        self,
        task: Task,
        *,
        workers: int = 1,
        backend: str = "local",
        progress: bool = False,
        solver_options: dict[str, Any] | None = None,
    ) -> None:
        self.task = task
        self.workers = workers
        self.backend = backend
        self.progress = progress
        self.solver_options = dict(solver_options or {})

    def __call__(self, starts: np.ndarray, taus: np.ndarray, thetas: np.ndarray | None = None) -> list[SolveResult]:
        """One result per start; with ``thetas`` (one robot per start) every solve takes its robot as NLP
        parameters (``TrajOptConfig(model_params=True)``) and returns ``grad_theta`` and ``knot_grad_theta``."""
        starts = np.atleast_2d(np.asarray(starts, dtype=np.float64))
        taus = np.asarray(taus, dtype=np.float64).reshape(-1)
        horizons = [tail_horizon(self.task, float(t)) for t in taus]
        out: list[SolveResult | None] = [None] * starts.shape[0]
        for k in dict.fromkeys(horizons):
            idx = [i for i, h in enumerate(horizons) if h == k]
            options = dict(self.solver_options)
            if k is not None:
                soft = self.task.profile.solver.tail_soft_bounds_weight
                options = {**TAIL_SOLVER_DEFAULTS, "soft_bounds_weight": soft, **options, "horizon": k}
            results = solve_many(
                self.task,
                starts[idx],
                taus[idx],
                thetas=None if thetas is None else np.asarray(thetas, dtype=np.float64)[idx],
                workers=self.workers,
                backend=self.backend,
                progress=self.progress,
                solver_options=options,
            )
            for i, result in zip(idx, results, strict=True):
                out[i] = result
        return [r for r in out if r is not None]

    def __repr__(self) -> str:
        return f"TrajoptBatchSolver({self.task!r}, workers={self.workers}, backend={self.backend!r})"


def trajopt_batch_solver(
    task: Task | str,
    *,
    workers: int = 1,
    backend: str = "local",
    progress: bool = False,
    solver_options: dict[str, Any] | None = None,
) -> TrajoptBatchSolver:
    """The real solver: ``solve_many`` on the full-horizon trajectory optimizer.

    ``task`` is a :class:`Task` or a registered name (resolved here, once, with ``make_task``); the Task object is
    what every ``solve_many`` call (and so every worker) gets. Requests whose ``tau`` is below T0 are tail problems
    (:func:`tail_horizon`): they are grouped by their number of intervals and solved with ``horizon=k`` and
    :data:`TAIL_SOLVER_DEFAULTS` (one optimizer per ``k`` and worker, built on first use and kept).

    Raises:
        TypeError: ``task`` is neither a Task nor a str.
        ValueError: an unknown task name or a malformed Task.
    """
    return TrajoptBatchSolver(
        resolve_task(task), workers=workers, backend=backend, progress=progress, solver_options=solver_options
    )


def solver_key(solver_options: dict[str, Any] | None, task: Task | str | None = None) -> str:
    """A stable text key of the real solver: its settings and a fingerprint of its code (caches are keyed by it).

    The fingerprint makes a cache (validation sets, cached solves) or a resumed run refuse results of an older
    optimizer after its code changed, instead of silently mixing the two. With ``task`` (a Task or a registered
    name) it is :func:`solver_fingerprint` of that task, so two tasks that differ in any parameter never share a key;
    without it the key is the code's alone (the caller must then keep tasks apart itself, e.g. by name).
    """
    return f"trajopt@{solver_fingerprint(task)}:" + json.dumps(solver_options or {}, sort_keys=True, default=str)


def solver_fingerprint(task: Task | str | None = None) -> str:
    """Short hash of the code that defines a solve and, given ``task``, of the task's content.

    Without ``task``: :func:`code_fingerprint` (the optimizer, tail defaults, transcription and built-in task
    sources). With a Task or a registered name: a hash of that and :meth:`Task.fingerprint` (the task's functions,
    parameters, bounds, sets and transcription settings).
    """
    code = code_fingerprint()
    if task is None:
        return code
    digest = hashlib.sha256(f"{code}:{resolve_task(task).fingerprint()}".encode())
    return digest.hexdigest()[:12]


@functools.cache
def code_fingerprint() -> str:
    """Short hash of the source of the modules that define a solve (optimizer, tail defaults, transcription, tasks,
    task profiles).

    Computed once per process, from the files of the modules this process imported.
    """
    digest = hashlib.sha256()
    for module in (
        seagul_learn.trajopt,
        sys.modules[__name__],  # the tail-solver defaults live here
        seagul_control.transcription,
        seagul_envs.tasks.base,
        seagul_envs.tasks.acrobot,
        seagul_envs.tasks.glider,
        seagul_envs.tasks.profile,  # the solver defaults of a new task
    ):
        digest.update(Path(str(module.__file__)).read_bytes())
    return digest.hexdigest()[:12]


class SolveRunner:
    """Numbers solves deterministically, reuses stored records, stores new ones atomically, counts failures."""

    def __init__(
        self,
        batch_solver: BatchSolver,
        dataset: Dataset | None = None,
        next_index: int = 0,
        chunk_size: int = 1,
        on_record: Callable[[SolveRecord], None] | None = None,
    ) -> None:
        """``chunk_size`` solves go to the batch solver at once (use the worker count: parallel, yet each
        finished chunk is on disk before the next starts)."""
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
        self.batch_solver = batch_solver
        self.dataset = dataset
        self.next_index = int(next_index)
        self.chunk_size = int(chunk_size)
        self.on_record = on_record
        self.num_solved = 0
        """Solves actually run by this runner (excludes reused records)."""
        self.num_reused = 0
        """Records taken from disk instead of solving again."""

    def solve(
        self,
        starts: np.ndarray,
        taus: np.ndarray,
        sampler: str,
        chains: Sequence[int] | None = None,
        steps: Sequence[int] | None = None,
        thetas: np.ndarray | None = None,
    ) -> list[SolveRecord]:
        """Solve (or reuse) one record per row of ``starts``, in order, with consecutive indices; ``thetas``
        (``(n, k)``, runs over robots) gives each solve its robot and goes to the batch solver as its third
        argument."""
        starts = np.atleast_2d(np.asarray(starts, dtype=np.float64))
        taus = np.asarray(taus, dtype=np.float64).reshape(-1)
        n = starts.shape[0]
        if taus.shape[0] != n:
            raise ValueError(f"need one tau per start: {n} starts, {taus.shape[0]} taus")
        if thetas is not None:
            thetas = np.asarray(thetas, dtype=np.float64)
            if thetas.ndim != 2 or thetas.shape[0] != n:
                raise ValueError(f"need one robot (a row of thetas) per start: {n} starts, thetas {thetas.shape}")
        chains = [-1] * n if chains is None else [int(c) for c in chains]
        steps = [0] * n if steps is None else [int(s) for s in steps]
        records: list[SolveRecord | None] = [None] * n
        pending: list[int] = []
        for i in range(n):
            index = self.next_index + i
            if self.dataset is not None and index in self.dataset:
                rec = self.dataset.read(index)
                theta = None if thetas is None else thetas[i]
                if not rec.same_request(starts[i], taus[i], theta) or rec.sampler != sampler:
                    planned = "" if theta is None else f" theta={theta.tolist()}"
                    stored = "" if not rec.n_params else f" theta={rec.theta.tolist()}"
                    raise DatasetError(
                        f"record {index} in {str(self.dataset.path)!r} answers another request "
                        f"({rec.sampler} x={rec.x_init.tolist()} tau={rec.tau}{stored}) than this run plans "
                        f"({sampler} x={starts[i].tolist()} tau={taus[i]}{planned}): the dataset belongs to another "
                        "configuration or seed"
                    )
                records[i] = rec
                self.num_reused += 1
            else:
                pending.append(i)
        for lo in range(0, len(pending), self.chunk_size):
            chunk = pending[lo : lo + self.chunk_size]
            if thetas is None:
                results = self.batch_solver(starts[chunk], taus[chunk])
            else:
                results = self.batch_solver(starts[chunk], taus[chunk], thetas[chunk])
            if len(results) != len(chunk):
                raise RuntimeError(f"batch solver returned {len(results)} results for {len(chunk)} starts")
            for i, result in zip(chunk, results, strict=True):
                rec = SolveRecord.from_result(result, self.next_index + i, sampler, chains[i], steps[i])
                if self.dataset is not None:
                    self.dataset.write(rec)
                records[i] = rec
                self.num_solved += 1
        self.next_index += n
        out = [r for r in records if r is not None]
        if self.on_record is not None:
            for rec in out:
                self.on_record(rec)
        return out


class CachedBatchSolver:
    """Wraps a batch solver with an on-disk cache of results keyed by ``(solver_name, task, x, tau)`` (bit-exact).

    For experiments that solve the same starts several times (the uniform baseline with and without Sobolev
    training, the shared pretraining set, adversarial chains starting at the baseline's starts). One ``.npz`` per
    result, written atomically, so concurrent processes sharing a cache are safe.

    The task enters the key by its :meth:`~seagul_envs.tasks.base.Task.fingerprint` (its content, not its name):
    ``task`` if given, else the batch solver's ``task`` attribute when that is a Task (as on the solver of
    :func:`trajopt_batch_solver`), so two tasks that differ in one parameter never share a cached solve. A batch
    solver without a Task is keyed by ``solver_name`` alone (``solver_key(options, task)`` puts the task there).

    Raises:
        TypeError: ``task`` is neither a Task nor a str.
        ValueError: ``task`` is an unknown name or a malformed Task.
    """

    def __init__(
        self,
        batch_solver: BatchSolver,
        cache_dir: str | os.PathLike[str],
        solver_name: str,
        task: Task | str | None = None,
    ) -> None:
        self.batch_solver = batch_solver
        self.cache_dir = Path(cache_dir)
        self.solver_name = solver_name
        if task is None:
            own = getattr(batch_solver, "task", None)
            task = own if isinstance(own, Task) else None
        self.task_fingerprint: str | None = None
        """The fingerprint of the task in every key (None: the keys are ``solver_name``, ``x`` and ``tau`` only)."""
        if task is not None:
            self.task_fingerprint = resolve_task(task).fingerprint()
        self.hits = 0
        self.misses = 0

    def _path(self, x: np.ndarray, tau: float, theta: np.ndarray | None = None) -> Path:
        digest = hashlib.sha256()
        digest.update(self.solver_name.encode())
        if self.task_fingerprint is not None:
            digest.update(b"\0task:" + self.task_fingerprint.encode())
        digest.update(np.ascontiguousarray(x, dtype=np.float64).tobytes())
        digest.update(np.float64(tau).tobytes())
        if theta is not None:  # a solve for a robot given as NLP parameters (none: the keys of older caches)
            digest.update(b"\0theta:" + np.ascontiguousarray(theta, dtype=np.float64).tobytes())
        key = digest.hexdigest()
        return self.cache_dir / key[:2] / f"{key}.npz"

    def __call__(self, starts: np.ndarray, taus: np.ndarray, thetas: np.ndarray | None = None) -> list[SolveResult]:
        starts = np.atleast_2d(np.asarray(starts, dtype=np.float64))
        taus = np.asarray(taus, dtype=np.float64).reshape(-1)
        rows = None if thetas is None else np.asarray(thetas, dtype=np.float64)
        out: list[SolveResult | None] = [None] * starts.shape[0]
        missing: list[int] = []
        for i, (x, tau) in enumerate(zip(starts, taus, strict=True)):
            path = self._path(x, tau, None if rows is None else rows[i])
            if path.is_file():
                try:
                    out[i] = _load_result(path)
                    self.hits += 1
                    continue
                except Exception:  # a damaged cache entry is solved again
                    path.unlink(missing_ok=True)
            missing.append(i)
        if missing:
            if rows is None:
                results = self.batch_solver(starts[missing], taus[missing])
            else:
                results = self.batch_solver(starts[missing], taus[missing], rows[missing])
            for i, result in zip(missing, results, strict=True):
                _save_result(self._path(starts[i], taus[i], None if rows is None else rows[i]), result)
                out[i] = result
            self.misses += len(missing)
        return [r for r in out if r is not None]


def _save_result(path: Path, result: SolveResult) -> None:
    # ``Any``, not ndarray, for numpy's stub: mypy lets a ``**`` mapping of arrays bind ``savez``'s ``allow_pickle``.
    arrays: dict[str, Any] = {}
    for f in fields(SolveResult):
        value = getattr(result, f.name)
        if value is None:
            continue  # an optional field (theta, grad_theta, knot_grad_theta of a solve without robots)
        if f.name == "attempts":
            arrays[f.name] = np.array([str(a) for a in value], dtype=np.str_)
        elif isinstance(value, str):
            arrays[f.name] = np.array(value, dtype=np.str_)
        else:
            arrays[f.name] = np.asarray(value)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    atomic_write_bytes(path, buffer.getvalue())


def _load_result(path: Path) -> SolveResult:
    with np.load(path, allow_pickle=False) as data:
        return SolveResult(
            x_init=np.array(data["x_init"], dtype=np.float64),
            tau=float(data["tau"]),
            success=bool(data["success"]),
            status=str(data["status"][()]),
            value=float(data["value"]),
            grad_x=np.array(data["grad_x"], dtype=np.float64),
            grad_tau=float(data["grad_tau"]),
            states=np.array(data["states"], dtype=np.float64),
            controls=np.array(data["controls"], dtype=np.float64),
            steps=np.array(data["steps"], dtype=np.float64),
            time_to_go=np.array(data["time_to_go"], dtype=np.float64),
            cost_to_go=np.array(data["cost_to_go"], dtype=np.float64),
            knot_grads=np.array(data["knot_grads"], dtype=np.float64),
            iterations=int(data["iterations"]),
            solve_time=float(data["solve_time"]),
            attempts=[str(a) for a in data["attempts"]],
            **{
                key: np.array(data[key], dtype=np.float64)
                for key in ("theta", "grad_theta", "knot_grad_theta")
                if key in data
            },
        )
