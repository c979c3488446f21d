"""Training runs of methods x seeds, shared by ``seagul reproduce``
(:class:`~seagul_learn.experiment.pipeline.Experiment`) and the closed-loop benchmark
(:mod:`seagul_learn.experiment.benchmark`): each run trains one
:class:`~seagul_learn.training.TrainConfig` into its directory, resumes from its checkpoint after an interruption and
is skipped once finished; the runs go one after the other or in parallel processes.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any


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
