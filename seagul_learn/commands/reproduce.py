"""``seagul reproduce``: the paper's experiment for one task end to end: the task's shipped controller in closed loop
beside LQR and the full-horizon MPC, then uniform, adversarial (SEAGuL) and closed-loop value-function learning at
an equal budget over paired seeds, closed-loop MPC statistics for every seed, and a report (see
:mod:`seagul_learn.experiment`). ``--methods`` names other methods of the same pipeline, the task's own recipe
included: ``seagul reproduce acrobot --methods shipped,uniform`` trains the shipped recipe (at its own budget) beside
the uniform sampler on the same schedule.

The options are one per :class:`~seagul_learn.experiment.ExperimentConfig` field (see
:mod:`seagul_learn.commands._config`; ``--ppo`` is an alias of ``--ppo-model``, itself a deprecated spelling of
``--sb3 MODEL --sb3-algo PPO``; ``--no-progress`` is the ``progress`` field's negative form; ``--shipped-jit``
compiles the shipped MPC); ``--out`` and ``--resume`` are not config fields. ``sb3_models`` is the one field declared
here rather than derived: ``--sb3 MODEL`` adds one model and may be repeated, ``--sb3-models A.zip,B.zip`` adds a
comma-separated list (both add to the same list, in the order given), e.g. ``seagul reproduce acrobot --sb3
runs/sac_a/model.zip --sb3 runs/sac_b/model.zip --sb3-algo SAC``."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from seagul_learn.cli import Command
from seagul_learn.commands._args import positive_int, task_argument
from seagul_learn.commands._config import (
    Option,
    add_dataclass_arguments,
    comma_list,
    dataclass_from_args,
    field_docstrings,
    plain_text,
)


class _AddModels(argparse.Action):
    """Add the model(s) of each occurrence to the ones given before (the value is parsed into a tuple)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        setattr(namespace, self.dest, (*getattr(namespace, self.dest, ()), *values))


def _one_model(value: str) -> tuple[str, ...]:
    """``--sb3 MODEL``: one path (commas included)."""
    return (value,)


def _method_list(names: tuple[str, ...]) -> Any:
    """``--methods A,B``: distinct known method names (an argument error names the unknown ones)."""

    def parse(value: str) -> tuple[str, ...]:
        methods = tuple(m.strip() for m in value.split(",") if m.strip())
        unknown = [m for m in methods if m not in names]
        if unknown or not methods:
            raise argparse.ArgumentTypeError(f"unknown methods {unknown or [value]}; choose from {', '.join(names)}")
        if len(set(methods)) != len(methods):
            raise argparse.ArgumentTypeError(f"a method is named twice: {value}")
        return methods

    return parse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the ``reproduce`` arguments: one per :class:`~seagul_learn.experiment.ExperimentConfig` field, then
    ``--out``/``--resume``."""
    from seagul_learn.experiment import METHOD_NAMES, SB3_ALGOS, ExperimentConfig

    add_dataclass_arguments(
        parser,
        ExperimentConfig,
        {
            "task": Option(
                positional=True,
                type=task_argument,
                metavar="TASK",
                help="acrobot, glider (or another registered name), or module:factory returning a Task",
            ),
            "preset": Option(
                choices=("quick", "paper", "smoke"), help="experiment size (smoke only checks the pipeline)"
            ),
            "seeds": Option(type=positive_int),
            "methods": Option(type=_method_list(METHOD_NAMES), metavar="A,B,..."),
            "workers": Option(type=positive_int, default=2),
            "backend": Option(choices=("local", "ray")),
            "ppo_model": Option(aliases=("--ppo",), metavar="MODEL"),
            "sb3_algo": Option(choices=SB3_ALGOS),
        },
        exclude=("sb3_models",),
    )
    # sb3_models by hand: repeating a derived option would keep only its last value.
    doc = plain_text(field_docstrings(ExperimentConfig)["sb3_models"])
    models: dict[str, Any] = {"dest": "sb3_models", "action": _AddModels, "default": ()}
    sb3_help = f"{doc} Repeatable (--sb3 A.zip --sb3 B.zip), all of the one --sb3-algo (default: none)"
    parser.add_argument("--sb3", type=_one_model, metavar="MODEL", help=sb3_help.replace("%", "%%"), **models)
    parser.add_argument(
        "--sb3-models",
        type=comma_list(str, "paths"),
        metavar="A,B,...",
        help="the --sb3 models as a comma-separated list (added to those of --sb3)",
        **models,
    )
    parser.add_argument("--out", default=None, help="run directory (default runs/<task>-<timestamp>)")
    parser.add_argument("--resume", metavar="DIR", default=None, help="finish an interrupted run in DIR")


def run(args: argparse.Namespace) -> int:
    """Run (or resume) the experiment; the last line printed is the path of ``report.md``."""
    from seagul_envs import Task
    from seagul_envs.tasks import task_label
    from seagul_learn.experiment import Experiment, ExperimentConfig

    if args.resume is not None:
        if args.out is not None and Path(args.out) != Path(args.resume):
            raise ValueError("give either --out (a new run) or --resume DIR (an interrupted one), not both")
        given = args.task if isinstance(args.task, Task) else None
        experiment = Experiment.resume(Path(args.resume), workers=args.workers, progress=args.progress, task=given)
        if task_label(experiment.config.task) != task_label(args.task):
            raise ValueError(
                f"{args.resume!r} is a {task_label(experiment.config.task)} run, not {task_label(args.task)}"
            )
    else:
        config = dataclass_from_args(ExperimentConfig, args)
        experiment = Experiment.create(config, None if args.out is None else Path(args.out))
    shown = "<the same module:factory>" if isinstance(args.task, Task) else args.task
    print(f"run directory: {experiment.out} (resume with: seagul reproduce {shown} --resume {experiment.out})")
    report = experiment.run()
    print(report)
    return 0


COMMAND = Command(
    name="reproduce",
    help="run the paper's experiment for a task (the shipped controller, then uniform vs SEAGuL vs closed-loop "
    "learning, or the --methods named, e.g. the shipped recipe, at an equal budget with per-seed MPC evaluation) and "
    "write a report",
    add_arguments=add_arguments,
    run=run,
)
