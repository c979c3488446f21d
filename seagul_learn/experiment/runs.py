"""Training runs of methods x seeds and the closed-loop evaluation of their snapshots, shared by ``seagul reproduce``
(:class:`~seagul_learn.experiment.pipeline.Experiment`) and the closed-loop benchmark
(:mod:`seagul_learn.experiment.benchmark`).

Training: each run trains one :class:`~seagul_learn.training.TrainConfig` into its directory, resumes from its
checkpoint after an interruption and is skipped once finished; the runs go one after the other or in parallel
processes (:func:`train_runs`).

Evaluation: a snapshot network is deployed as a limited-lookahead MPC (:func:`deployment_options`,
:func:`network_spec`) and run from the start grid and from the held-out starts
(:func:`seagul_control.evaluation.heldout_starts`, one fixed seed for every controller) in one call
(:func:`evaluate_snapshot`); :func:`success_fields` turns the two lists of episodes into the ``success_rate``,
``heldout_success_rate`` and ``grid_success`` both report. The grid measures coverage of X0 at a known resolution;
the held-out starts are uniform draws no training stream saw, the check that a grid success is not the grid's.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


def train_one(config: Any, out: str | Path, cache: Path | None = None, workers: int = 1, backend: str = "local") -> str:
    """One training run of ``config`` (a :class:`~seagul_learn.training.TrainConfig`) in ``out``, resumed from its
    checkpoint if one is there; a run with its ``metrics.json`` is finished and left alone. Returns ``out``.

    ``cache``: the solves go through the bit-exact solve cache there (``seagul reproduce``), with ``workers``
    solver processes on ``backend`` and torch on one thread (the runs are the parallel unit). None: ``train``'s own
    solver, the config as given (the closed-loop benchmark).
    """
    from seagul_learn.training import train

    out = Path(out)
    if (out / "metrics.json").is_file():
        return str(out)
    resume = (out / "config.json").is_file()
    if cache is None:
        train(config, out, resume=resume)
        return str(out)
    import torch

    from seagul_learn.solving import CachedBatchSolver, solver_key, trajopt_batch_solver

    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    key = solver_key(None, config.task)
    solver = CachedBatchSolver(trajopt_batch_solver(config.task, workers=workers, backend=backend), cache, key)
    config = config.replaced(**{"runtime.workers": workers, "runtime.backend": backend})
    train(config, out, resume=resume, batch_solver=solver, solver_name=key)
    return str(out)


def train_runs(
    jobs: Sequence[tuple[Any, str | Path]],
    workers: int = 1,
    backend: str = "local",
    cache: Path | None = None,
    progress: bool = False,
    total: int | None = None,
) -> None:
    """Every ``(TrainConfig, run directory)`` of ``jobs`` (:func:`train_one`): one after the other with ``workers``
    solver processes each when ``workers`` is 1 or on Ray (which spreads the solves inside a run), else ``workers``
    runs at a time. The order of ``jobs`` is the order they start in (put the longest first). ``total``: the bar's
    length when some runs of it are done already."""
    from joblib import Parallel, delayed
    from tqdm.auto import tqdm

    if not jobs:
        return
    total = len(jobs) if total is None else total
    bar = tqdm(total=total, initial=total - len(jobs), desc="training runs", disable=not progress)
    if backend == "ray" or workers == 1:
        for config, out in jobs:
            train_one(config, out, cache, workers=workers, backend=backend)
            bar.update(1)
    else:
        pending = (delayed(train_one)(config, out, cache) for config, out in jobs)
        for _ in Parallel(n_jobs=workers, return_as="generator_unordered")(pending):
            bar.update(1)
    bar.close()


# ---------------------------------------------------------------------------------------------- evaluation
def deployment_options(
    horizon: int,
    trust_region: str,
    goal_blend: float = 0.0,
    solver: str | None = None,
    jit: bool | None = None,
) -> tuple[tuple[str, Any], ...]:
    """Constructor options of a deployed :class:`~seagul_control.mpc.LimitedLookaheadMPC`: ``horizon`` lookahead
    steps, the ``trust_region`` guard, then, only when given, the NLP ``solver`` (``"ipopt"``), ``jit`` (compile the
    MPC) and ``goal_blend`` (0 = off, left out)."""
    options: list[tuple[str, Any]] = [("horizon", int(horizon))]
    if solver is not None:
        options.append(("solver", solver))
    options.append(("trust_region", trust_region))
    if jit is not None:
        options.append(("jit", bool(jit)))
    if goal_blend > 0:
        options.append(("goal_blend", float(goal_blend)))
    return tuple(options)


def network_spec(label: str, path: str | Path, options: tuple[tuple[str, Any], ...]) -> Any:
    """The :class:`~seagul_control.evaluation.PolicySpec` of a snapshot network ``path`` deployed with ``options``
    (:func:`deployment_options`), named ``label`` in tables."""
    from seagul_control.evaluation import PolicySpec

    return PolicySpec("mpc", label, str(path), options)


def evaluate_snapshot(
    task: Any,
    spec: Any,
    grid_starts: np.ndarray,
    heldout: int | np.ndarray,
    workers: int = 1,
    progress: bool = False,
    record: bool = False,
    record_queries: bool = False,
) -> tuple[list[Any], list[Any]]:
    """``(grid episodes, held-out episodes)`` of one policy ``spec`` (a snapshot network's :func:`network_spec`, or
    any :class:`~seagul_control.evaluation.PolicySpec`) from ``grid_starts`` and from the held-out starts.

    ``heldout``: their number, drawn by :func:`seagul_control.evaluation.heldout_starts` (the same starts for
    every controller, run and benchmark), or the start rows themselves. Both sets run in one
    :func:`~seagul_control.evaluation.evaluate` call, so the episodes share the worker processes (and a compiled
    MPC); ``record``/``record_queries`` as there.
    """
    from seagul_control.evaluation import evaluate, heldout_starts

    held = heldout_starts(task, heldout) if isinstance(heldout, int | np.integer) else np.asarray(heldout)
    grid = np.asarray(grid_starts, dtype=np.float64)
    nx = held.shape[1] if held.ndim == 2 and held.size else grid.shape[-1]
    starts = np.vstack([grid.reshape(-1, nx), held.reshape(-1, nx)])
    if len(starts) == 0:
        return [], []
    results = evaluate(task, [spec], starts, workers, progress, record, record_queries=record_queries)
    n_grid = len(grid.reshape(-1, nx))
    return list(results[:n_grid]), list(results[n_grid:])


def success_fields(grid: Sequence[Any], heldout: Sequence[Any]) -> dict[str, Any]:
    """``success_rate`` (grid), ``heldout_success_rate`` (NaN without held-out episodes) and ``grid_success`` (one
    bool per grid start, in grid order) of :func:`evaluate_snapshot`'s episodes."""
    return {
        "success_rate": float(np.mean([r.success for r in grid])) if grid else float("nan"),
        "heldout_success_rate": float(np.mean([r.success for r in heldout])) if heldout else float("nan"),
        "grid_success": [bool(r.success) for r in grid],
    }
