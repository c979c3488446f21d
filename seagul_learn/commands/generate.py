"""``seagul generate``: solve uniform draws from X0 (or the task's validation set) into a dataset."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from seagul_envs import resolve_task
from seagul_learn.cli import Command
from seagul_learn.commands._args import add_parallel_arguments, add_task_argument, positive_int
from seagul_learn.commands.train import json_object
from seagul_learn.dataset import Dataset, count_failures


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the ``generate`` arguments."""
    add_task_argument(parser)
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--num", type=positive_int, help="number of uniform draws from X0 (at the nominal tau)")
    what.add_argument("--validation", action="store_true", help="the task's validation set (cached, see --cache-dir)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the uniform draws")
    parser.add_argument("--out", help="dataset directory (required with --num; reused by --resume)")
    parser.add_argument("--resume", action="store_true", help="continue an interrupted --num run in --out")
    parser.add_argument("--cache-dir", default=None, help="validation-set cache (default $SEAGUL_CACHE_DIR)")
    parser.add_argument("--solver-options", type=json_object, default=None, help="trajectory-optimizer options (JSON)")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    add_parallel_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Solve and store; prints counts and, last, the dataset directory."""
    # Loaded when the command runs, so that `seagul --help` stays fast: tqdm, the solver stack (casadi, the
    # transcription) and the training module (torch).
    from tqdm.auto import tqdm

    from seagul_learn.solving import SolveRunner, solver_key, trajopt_batch_solver
    from seagul_learn.training import default_cache_dir, validation_dataset

    if args.num is not None and not args.out:
        raise ValueError("--out is required with --num")
    task = resolve_task(args.task)  # resolved once: the Task object goes to the workers
    solver = trajopt_batch_solver(task, workers=args.workers, backend=args.backend, solver_options=args.solver_options)
    key = solver_key(args.solver_options, task)
    if args.validation:
        cache = args.cache_dir or default_cache_dir()
        records = validation_dataset(task, solver, key, cache, args.workers, not args.no_progress)
        print(f"{task.name} validation set: {len(records)} solves, {count_failures(records)} failed")
        print(cache)
        return 0
    out = Path(args.out)
    if (out / "dataset.json").is_file() and not args.resume:
        raise FileExistsError(f"dataset {str(out)!r} already exists; pass --resume to complete it or choose a new one")
    dataset = Dataset.open(out, task.name, meta={"solver": key, "seed": args.seed, "num": args.num, "kind": "uniform"})
    starts = task.sample_x0(np.random.default_rng([args.seed, 0]), args.num)
    runner = SolveRunner(solver, dataset, chunk_size=args.workers)
    records = []
    with tqdm(total=args.num, desc=f"solving {task.name}", disable=args.no_progress) as bar:
        for lo in range(0, args.num, args.workers):
            hi = min(lo + args.workers, args.num)
            records += runner.solve(starts[lo:hi], np.full(hi - lo, task.tau_nominal), "uniform")
            bar.update(hi - lo)
    print(f"{task.name}: {len(records)} solves ({runner.num_reused} reused), {count_failures(records)} failed")
    print(dataset.path)
    return 0


COMMAND = Command(
    name="generate",
    help="solve uniform draws from X0, or the validation set, into a dataset directory",
    add_arguments=add_arguments,
    run=run,
)
