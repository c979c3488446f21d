"""``seagul reproduce``: the paper's experiment for one task end to end: uniform, adversarial (SEAGuL) and
closed-loop value-function learning over paired seeds, closed-loop MPC statistics for every seed, and a report (see
:mod:`seagul_learn.experiment`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from seagul_learn.cli import Command
from seagul_learn.commands._args import positive_int, task_name


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the ``reproduce`` arguments."""
    parser.add_argument("task", type=task_name, help="acrobot or glider")
    parser.add_argument(
        "--preset",
        choices=("quick", "paper", "smoke"),
        default="quick",
        help="experiment size (default quick; smoke only checks the pipeline)",
    )
    parser.add_argument("--seeds", type=positive_int, default=None, help="paired seeds (default: the preset's)")
    parser.add_argument("--workers", type=positive_int, default=2, help="parallel processes (default 2)")
    parser.add_argument("--backend", choices=("local", "ray"), default="local", help="where solves run")
    parser.add_argument("--out", default=None, help="run directory (default runs/<task>-<timestamp>)")
    parser.add_argument("--resume", metavar="DIR", default=None, help="finish an interrupted run in DIR")
    parser.add_argument("--ppo", metavar="MODEL", default=None, help="a saved SB3 PPO model to evaluate as well")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")


def run(args: argparse.Namespace) -> int:
    """Run (or resume) the experiment; the last line printed is the path of ``report.md``."""
    from seagul_learn.experiment import Experiment, ExperimentConfig

    if args.resume is not None:
        if args.out is not None and Path(args.out) != Path(args.resume):
            raise ValueError("give either --out (a new run) or --resume DIR (an interrupted one), not both")
        experiment = Experiment.resume(Path(args.resume), workers=args.workers, progress=not args.no_progress)
        if experiment.config.task != args.task:
            raise ValueError(f"{args.resume!r} is a {experiment.config.task} run, not {args.task}")
    else:
        config = ExperimentConfig(
            task=args.task,
            preset=args.preset,
            seeds=args.seeds,
            workers=args.workers,
            backend=args.backend,
            ppo_model=args.ppo,
            progress=not args.no_progress,
        )
        experiment = Experiment.create(config, None if args.out is None else Path(args.out))
    print(f"run directory: {experiment.out} (resume with: seagul reproduce {args.task} --resume {experiment.out})")
    report = experiment.run()
    print(report)
    return 0


COMMAND = Command(
    name="reproduce",
    help="run the paper's experiment for a task (uniform vs SEAGuL vs closed-loop learning, per-seed MPC "
    "evaluation) and write a report",
    add_arguments=add_arguments,
    run=run,
)
