"""The validation set of a training run: solved once per task and solver settings, cached on disk.

Each task's set is ``task.profile.validation_spec(task)`` (docs/reference/spec.md §3.6/§4.6): acrobot a 10 x 10 grid
over ``(th1, th2)`` at zero velocity plus 100 uniform draws from X0; glider a 6 x 6 x 6 grid over ``(x, z, dx)`` plus
250 uniform draws; a new task a 10 x 10 grid over two coordinates plus 100 draws; all at the nominal ``tau``. The
random part uses a fixed seed (:data:`~seagul_envs.tasks.profile.VALIDATION_SEED`), so every training seed is
validated on the same set.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from seagul_control._io import cache_dir as seagul_cache_dir
from seagul_envs import Task
from seagul_envs.tasks.profile import VALIDATION_SEED, ValidationSpec
from seagul_learn.dataset import Dataset, SolveRecord
from seagul_learn.fitting import STREAM_VALIDATION_ROBOTS
from seagul_learn.solving import BatchSolver

_VALIDATION_SEED = VALIDATION_SEED  # one validation set for all training seeds (seagul_envs.tasks.profile)

_LOADED: dict[str, tuple[tuple[int, int], list[SolveRecord]]] = {}
"""Complete validation sets read in this process, by cache directory, with the directory's stamp
(:func:`_stamp`) when they were read: a process that trains many runs (seeds, samplers, an experiment) reads each
set's record files once instead of once per run."""


def _stamp(dataset: Dataset) -> tuple[int, int]:
    """The records folder's modification time and file count: a record written, replaced (atomic renames) or removed
    changes it, so a set that changed on disk is read again."""
    folder = dataset.records_dir
    return folder.stat().st_mtime_ns, sum(1 for _ in folder.iterdir())


def default_cache_dir() -> Path:
    """``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul`` (:func:`seagul_control._io.cache_dir`)."""
    return seagul_cache_dir()


def validation_dataset(
    task: Task,
    batch_solver: BatchSolver,
    solver_name: str,
    cache_dir: str | os.PathLike[str] | None = None,
    chunk_size: int = 1,
    progress: bool = False,
    spec: ValidationSpec | None = None,
    model_params: bool = False,
) -> list[SolveRecord]:
    """Solve (or load from the cache) the task's validation set; returns one record per validation start.

    The set is ``spec`` or the task's (``task.profile.validation_spec(task)``); with ``model_params`` every start
    is solved for a robot drawn uniformly from Theta (:func:`validation_robots`, a fixed seed). The cache entry is
    keyed by ``solver_name`` (give ``solver_key(options, task)`` for the real solver), the spec, ``tau`` and the task's
    fingerprint, so a variant of a task (one parameter changed, same name) gets a validation set of its own. A
    complete set is read from disk once per process (:data:`_LOADED`): the records returned are shared between calls
    and must not be modified.
    """
    spec = spec or task.profile.validation_spec(task)
    starts = spec.starts(task)
    robots = validation_robots(task, starts.shape[0]) if model_params else None
    meta: dict[str, Any] = {"solver": solver_name, "spec": asdict(spec), "tau": task.tau_nominal}
    meta["task"] = task.fingerprint()
    if robots is not None:
        meta["robots"] = "uniform over Theta, seed " + str(_VALIDATION_SEED)
    key = hashlib.sha256(json.dumps(meta, sort_keys=True).encode()).hexdigest()[:16]
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    dataset = Dataset.open(root / f"validation-{task.name}-{key}", task.name, meta=meta)
    have = set(dataset.indices())
    todo = [i for i in range(starts.shape[0]) if i not in have]
    bar = tqdm(total=starts.shape[0], initial=len(have), desc=f"validation set ({task.name})", disable=not progress)
    for lo in range(0, len(todo), chunk_size):
        chunk = todo[lo : lo + chunk_size]
        taus = np.full(len(chunk), task.tau_nominal)
        if robots is None:
            results = batch_solver(starts[chunk], taus)
        else:
            results = batch_solver(starts[chunk], taus, robots[chunk])
        for i, result in zip(chunk, results, strict=True):
            dataset.write(SolveRecord.from_result(result, i, "validation"), exist_ok=True)  # races are harmless
        bar.update(len(chunk))
    bar.close()
    cache_key, stamp = str(dataset.path.resolve()), _stamp(dataset)
    loaded = _LOADED.get(cache_key)
    if loaded is not None and loaded[0] == stamp and len(loaded[1]) == starts.shape[0]:
        return list(loaded[1])  # read-only records, already checked against these starts below
    records = [dataset.read(i) for i in range(starts.shape[0])]
    for i, rec in enumerate(records):
        if not rec.same_request(starts[i], task.tau_nominal, None if robots is None else robots[i]):
            raise RuntimeError(f"validation cache {str(dataset.path)!r} holds another start at index {i}")
    _LOADED[cache_key] = (stamp, records)
    return list(records)


def validation_robots(task: Task, n: int) -> np.ndarray:
    """The robots of a validation set over robots: ``n`` uniform draws from Theta with the validation seed (the same
    for every training seed, sampler and run)."""
    if task.parameters is None:
        raise ValueError(f"{task.name} declares no physical parameters (Task.parameters)")
    rng = np.random.default_rng([_VALIDATION_SEED, STREAM_VALIDATION_ROBOTS])
    return task.parameters.sample(rng, n).reshape(n, task.parameters.size)
