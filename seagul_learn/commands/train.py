"""``seagul train``: one SEAGuL (or uniform-baseline) training run into a run directory.

The options are derived from :class:`~seagul_learn.training.TrainConfig` (see :mod:`seagul_learn.commands._config`):
one ``--field-name`` per field, typed by its annotation, defaulting to its default, helped by its docstring, so a new
field needs no edit here. :func:`train_options` only adds validating parsers (whose errors name the accepted range),
choices and the ``--sobolev`` alias of ``--sobolev-weight``. ``--no-progress`` is the ``progress``
field's negative form. ``--out`` and ``--resume`` are not config fields.

``--recipe`` chooses what the options that are not given take: ``task`` (default) the task's measured best
settings (``task.profile.train_recipe``, :meth:`~seagul_learn.training.TrainConfig.recipe`; the acrobot's and the
glider's are the closed-loop recipes of docs/experiments/closed-loop.md), ``paper`` the dataclass defaults (the paper's
settings: adversarial sampler, 1 x 32 tanh, 100 solves). Options given always win. The defaults the help shows are
the dataclass's.
"""

from __future__ import annotations

import argparse
from typing import Any

from seagul_envs import available_tasks
from seagul_learn.cli import Command
from seagul_learn.commands._args import (
    fraction,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    task_argument,
)
from seagul_learn.commands._config import Option, add_dataclass_arguments, json_value


def hidden_widths(value: str) -> tuple[int, ...]:
    """``"32"`` or ``"64,32"``: hidden-layer widths."""
    try:
        widths = tuple(int(v) for v in value.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers like 32 or 64,32, got {value!r}") from None
    if not widths or any(w < 1 for w in widths):
        raise argparse.ArgumentTypeError(f"widths must be >= 1, got {value!r}")
    return widths


def budgets(value: str) -> tuple[int, ...]:
    """``"100,300,1000"``: solve counts."""
    if not value.strip():
        return ()
    try:
        out = tuple(int(v) for v in value.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers like 100,300, got {value!r}") from None
    if any(b < 1 for b in out):
        raise argparse.ArgumentTypeError(f"budgets must be >= 1, got {value!r}")
    return out


json_object = json_value(dict)
"""A JSON object (solver options)."""

RECIPES = ("task", "paper")
"""What ``--recipe`` accepts (module docstring)."""

_NOT_GIVEN: Any = type("NotGiven", (), {"__repr__": lambda self: "<not given>"})()
"""The parsed value of a config option the command line did not give (it takes the recipe's value)."""


def train_options() -> dict[str, Option]:
    """Refinements of the options derived from :class:`~seagul_learn.training.TrainConfig` (validating parsers,
    choices, the ``--sobolev`` spelling); every field without an entry gets the option its annotation implies."""
    from seagul_learn.training import SAMPLERS

    return {
        "task": Option(
            type=task_argument,
            required=True,
            metavar="NAME|MODULE:FACTORY",
            note=f"a name, one of: {', '.join(available_tasks())}; or module:factory returning a Task",
        ),
        "sampler": Option(choices=SAMPLERS),
        "budget": Option(type=positive_int),
        "solves_per_round": Option(type=positive_int),
        "train_steps_per_round": Option(type=non_negative_int),
        "batch_size": Option(type=positive_int),
        "newest_fraction": Option(type=fraction),
        "lr": Option(type=positive_float),
        "sobolev_weight": Option(type=non_negative_float, aliases=("--sobolev",)),
        "hidden": Option(type=hidden_widths, metavar="W[,W...]"),
        "ensemble": Option(type=positive_int),
        "ensemble_pessimism": Option(type=non_negative_float),
        "pretrain_solves": Option(type=positive_int),
        "pretrain_steps": Option(type=non_negative_int),
        "adv_max_steps": Option(type=positive_int),
        "adv_step_fraction": Option(type=positive_float),
        "adv_eps": Option(type=non_negative_float),
        "adv_optimizer": Option(choices=("pga", "adam")),
        "adv_projection": Option(choices=("clip", "reflect")),
        "adv_uniform_fraction": Option(type=fraction),
        "cl_episodes": Option(type=positive_int),
        "cl_horizon": Option(type=non_negative_int),
        "cl_trust_region": Option(choices=("none", "lqr", "box")),
        "cl_warmup_rounds": Option(type=non_negative_int),
        "cl_selection": Option(choices=("farthest", "spread", "lowest", "random")),
        "cl_tail_stride": Option(type=positive_int),
        "cl_uniform_fraction": Option(type=fraction),
        "cl_uniform_solves": Option(type=non_negative_int),
        "cl_visited_fraction": Option(type=fraction),
        "value_cap": Option(type=non_negative_float),
        "snapshots": Option(type=budgets, metavar="N[,N...]"),
        "eval_every": Option(type=non_negative_int),
        "torch_threads": Option(type=positive_int),
        "workers": Option(type=positive_int),
        "backend": Option(choices=("local", "ray")),
        "solver_options": Option(type=json_object, metavar="JSON"),
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the ``train`` arguments: ``--out``/``--resume``, then one option per
    :class:`~seagul_learn.training.TrainConfig` field (flag, type, default and help all from the dataclass)."""
    from seagul_learn.training import TrainConfig

    run_group = parser.add_argument_group("run directory")
    run_group.add_argument("--out", required=True, help="run directory (created; must be new unless --resume)")
    run_group.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    run_group.add_argument(
        "--recipe",
        choices=RECIPES,
        default="task",
        help="what the options not given take: 'task' the task's measured best settings (task.profile.train_recipe; "
        "the acrobot's: the closed-loop sampler, 1,000 solves, 2 x 64; ignored when --sampler names another sampler), "
        "'paper' the defaults shown below (the paper's settings) (default: task)",
    )
    config_group = parser.add_argument_group(
        "training configuration",
        "one option per TrainConfig field (seagul_learn.training); the defaults shown are the dataclass's (--recipe "
        "paper), an option not given takes the task's recipe value (--recipe task)",
    )
    actions = add_dataclass_arguments(config_group, TrainConfig, train_options())
    # Options the command line does not give are told apart from those it gives with a default's value.
    config_group.set_defaults(**{a.dest: _NOT_GIVEN for a in actions if not a.required})


def config_from_args(args: argparse.Namespace) -> Any:
    """The :class:`~seagul_learn.training.TrainConfig` of parsed arguments: the options given, the rest from the
    task's recipe (``--recipe task``) or the dataclass defaults (``--recipe paper``)."""
    import dataclasses

    from seagul_learn.training import TrainConfig

    given = {
        f.name: getattr(args, f.name)
        for f in dataclasses.fields(TrainConfig)
        if hasattr(args, f.name) and getattr(args, f.name) is not _NOT_GIVEN
    }
    if getattr(args, "recipe", "task") == "paper":
        return TrainConfig(**given)
    task = given.pop("task")
    try:
        return TrainConfig.recipe(task, **given)
    except ValueError as exc:
        raise ValueError(
            f"{exc} (the options not given come from the task's recipe, task.profile.train_recipe; --recipe paper "
            "starts from the defaults shown by --help instead)"
        ) from exc


def run(args: argparse.Namespace) -> int:
    """Train and print a summary; the last line is the run directory."""
    from seagul_envs.tasks import task_label
    from seagul_learn.training import train

    config = config_from_args(args)
    result = train(config, args.out, resume=args.resume)
    last = result.metrics[-1]
    print(
        f"{task_label(args.task)} {config.sampler}: {result.num_solves} solves ({result.num_failures} failed), "
        f"{last.train_steps} training steps, validation mse_initial={last.mse_initial:.4g} "
        f"mse_all_knots={last.mse_all_knots:.4g}"
    )
    print(result.out_dir)
    return 0


COMMAND = Command(
    name="train",
    help="train a value network with adversarial (SEAGuL) or uniform sampling",
    add_arguments=add_arguments,
    run=run,
)
