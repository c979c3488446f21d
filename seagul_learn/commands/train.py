"""``seagul train``: one SEAGuL (or uniform-baseline) training run into a run directory.

The configuration flags are derived by `tyro <https://brentyi.github.io/tyro/>`_ from
:class:`~seagul_learn.config.TrainConfig` and its parts (CleanRL's pattern: the dataclasses are the interface): one
flag per field, nested by part (``--schedule.solves-per-round 50``, ``--loss.sobolev-weight 1``, ``--network.hidden
64 64``, ``--runtime.no-progress``), typed by its annotation, helped by its docstring, so a new field needs no edit
here. The sampler is chosen as tyro chooses a member of a union, by a subcommand word: ``sampler:uniform``,
``sampler:adversarial`` or ``sampler:closed-loop``, followed by (or preceded by) its options
(``--sampler.episodes 20``); without the word the sampler of the starting config keeps its class.

What the flags start from: ``--config FILE`` (a saved :meth:`~seagul_learn.config.TrainConfig.save`, YAML or JSON, or
a run's ``config.json``), else the task's recipe ``--recipe NAME`` (default ``default``, the task's measured best:
``seagul_learn/recipes/<task>.yml``; ``paper`` the paper's settings; ``shipped`` the shipped network's run). Naming
another sampler than the recipe's starts from the dataclass defaults (a recipe's settings belong to its sampler),
as :meth:`~seagul_learn.config.TrainConfig.recipe` does. ``--out``, ``--resume``, ``--task``, ``--recipe``,
``--config`` and ``--solver-options JSON`` are not config flags.

**The flat flags of earlier versions keep working** (``--sampler closed-loop --cl-episodes 20 --budget 100
--hidden 64,64 --sobolev 1``, ``--recipe task``): :func:`translate_legacy` rewrites them into the nested ones and a
deprecation message on stderr names each new spelling. A flat flag of a sampler that is not the chosen one is
dropped, as the old parser ignored it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from typing import Any

import tyro

from seagul_envs import available_tasks
from seagul_envs.tasks import task_label
from seagul_learn.cli import Command
from seagul_learn.commands._args import task_argument
from seagul_learn.commands._json import json_value
from seagul_learn.config_legacy import LEGACY_NAMES, new_name
from seagul_learn.config_parts import SECTIONS
from seagul_learn.recipes import recipe_names

RECIPE_ALIASES = {"task": "default"}
"""``--recipe`` spellings of earlier versions: ``task`` is now the ``default`` recipe."""

SAMPLER_WORDS = ("sampler:uniform", "sampler:adversarial", "sampler:closed-loop")
"""The subcommand words that choose the sampler."""


def run_parser() -> argparse.ArgumentParser:
    """The options of ``seagul train`` that are not config fields (the run directory, where the config starts)."""
    parser = argparse.ArgumentParser(prog="seagul train", add_help=False)
    parser.add_argument("--out", help="run directory (created; must be new unless --resume)")
    parser.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    parser.add_argument(
        "--task",
        type=task_argument,
        metavar="NAME|MODULE:FACTORY",
        help=f"the task: a name, one of: {', '.join(available_tasks())}; or module:factory returning a Task "
        "(required unless --config gives it)",
    )
    parser.add_argument(
        "--recipe",
        default=None,
        metavar="NAME",
        help="the task's recipe the flags start from (seagul_learn/recipes/<task>.yml): 'default' (the task's "
        "measured best), 'paper' (the paper's settings), 'shipped' (the shipped network's run), ... (default: default)",
    )
    parser.add_argument("--config", metavar="FILE", help="start from a saved config (.yml/.yaml/.json) instead")
    parser.add_argument(
        "--solver-options",
        type=json_object,
        metavar="JSON",
        help="options of the trajectory optimizer, a JSON object (part of the validation-cache key)",
    )
    return parser


json_object = json_value(dict)
"""A JSON object (solver options)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``train`` subparser of ``seagul --help`` (and of the docs check): the run options. The config flags are
    tyro's (``seagul train --help`` prints them); :func:`main` parses the command line."""
    for action in run_parser()._actions:
        parser._add_action(action)
    parser.add_argument("config_flags", nargs=argparse.REMAINDER, help="TrainConfig flags (seagul train --help)")


# --------------------------------------------------------------------------------------------- the old flags
def _legacy_flags() -> dict[str, str]:
    """``--old-flag`` -> flat field name, for every flat field of earlier versions."""
    flags = {"--" + name.replace("_", "-"): name for name in LEGACY_NAMES}
    flags["--sobolev"] = "sobolev_weight"
    return flags


def _new_flag(name: str) -> str:
    return "--" + new_name(name).replace("_", "-")


def translate_legacy(argv: Sequence[str], sampler: str) -> tuple[list[str], list[str]]:
    """``argv`` with the flat flags of earlier versions rewritten into the nested ones; returns the new argv and one
    ``"--old -> --new"`` note per rewritten flag (empty: nothing to say). ``sampler`` is the sampler of the starting
    config, which a flat ``--sampler NAME`` replaces; flat flags of another sampler are dropped (noted)."""
    flags = _legacy_flags()
    args = _split_equals(argv)
    chosen = sampler
    for i, arg in enumerate(args[:-1]):
        if arg == "--sampler":
            chosen = args[i + 1]
    out: list[str] = []
    notes: list[str] = []
    i = 0
    while i < len(args):
        arg = args[i]
        if arg == "--sampler" and i + 1 < len(args):
            out[:0] = [f"sampler:{args[i + 1]}"]
            notes.append(f"--sampler {args[i + 1]} -> sampler:{args[i + 1]}")
            i += 2
            continue
        negated = arg.startswith("--no-") and ("--" + arg[5:]) in flags
        name = flags.get("--" + arg[5:] if negated else arg)
        if name is None:
            out.append(arg)
            i += 1
            continue
        owner = LEGACY_NAMES[name][2]
        new = _new_flag(name)
        takes_value = not negated and i + 1 < len(args) and not _is_bool_field(name)
        value = args[i + 1] if takes_value else None
        spelled = f"{arg} {value}" if value is not None else arg
        if owner is not None and owner != chosen:
            notes.append(f"{spelled} (ignored: the {chosen} sampler has no such option)")
            i += 2 if takes_value else 1
            continue
        if negated:
            head, _, last = new.rpartition(".")
            tokens = [f"{head}.no-{last}" if head else f"--no-{new[2:]}"]
        elif value is None:
            tokens = [new]
        else:
            tokens = [new, *_values(name, value)]
        out += tokens
        notes.append(f"{spelled} -> {' '.join(tokens)}")
        i += 2 if takes_value else 1
    return out, notes


def _split_equals(argv: Sequence[str]) -> list[str]:
    """``--flag=value`` as ``--flag value`` (for the old flags)."""
    flags = _legacy_flags()
    out: list[str] = []
    for arg in argv:
        head, eq, value = arg.partition("=")
        if eq and head in (*flags, "--sampler"):
            out += [head, value]
        else:
            out.append(arg)
    return out


def _is_bool_field(name: str) -> bool:
    """Whether the flat field ``name`` was a flag (``--name`` / ``--no-name``, no value)."""
    from seagul_learn.config import SAMPLER_OPTIONS  # tyro and the recipes load only when a flag is translated

    part, field_name, owner = LEGACY_NAMES[name]
    cls = SAMPLER_OPTIONS[str(owner)] if part == "sampler" else SECTIONS[str(part)]
    field = next(f for f in dataclasses.fields(cls) if f.name == field_name)
    return isinstance(field.default, bool)


def _values(name: str, value: str) -> list[str]:
    """An old flag's value as the new flag takes it: comma lists as separate words, ``cl_horizon 0`` as None."""
    if name in ("hidden", "snapshots"):
        return [v for v in value.split(",") if v.strip()]
    if name == "cl_horizon" and value.strip() == "0":
        return ["None"]
    return [value]


# ----------------------------------------------------------------------------------------------- the parse
def parse(argv: Sequence[str]) -> tuple[Any, argparse.Namespace]:
    """``(TrainConfig, run options)`` of a ``seagul train`` command line (without the word ``train``).

    Raises:
        SystemExit: bad flags (status 2, tyro's or argparse's message naming the flag) or ``--help`` (status 0).
        ValueError: a value the config refuses (naming the field), an unknown recipe, or a missing ``--task``.
    """
    from seagul_learn.config import TrainConfig

    parser = run_parser()
    try:
        run, rest = parser.parse_known_args(list(argv))
    except SystemExit:
        raise
    wants_help = any(a in ("-h", "--help") for a in rest)
    recipe = run.recipe
    if recipe in RECIPE_ALIASES:
        print(f"seagul train: --recipe {recipe} is deprecated; use --recipe {RECIPE_ALIASES[recipe]}", file=sys.stderr)
        recipe = RECIPE_ALIASES[recipe]
    if run.config is not None:
        base = TrainConfig.load(run.config)
        if run.task is not None:
            base = base.replaced(task=run.task)
        from_recipe = False
    elif run.task is not None:
        base = TrainConfig.recipe(run.task, recipe or "default")
        from_recipe = True
    elif wants_help:
        base, from_recipe = TrainConfig(), False
    else:
        parser.error("the following arguments are required: --task (or --config)")
    translated, notes = translate_legacy(rest, base.sampler.name)
    if notes:
        print(
            "seagul train: these flags are deprecated, read as their nested spelling: " + "; ".join(notes),
            file=sys.stderr,
        )
    words = [a for a in translated if a in SAMPLER_WORDS]
    if not words and any(a.startswith("--sampler.") for a in translated):
        words = [f"sampler:{base.sampler.name}"]  # the sampler's flags are read under its word (tyro's subcommand)
    if words:
        translated = [words[-1], *(a for a in translated if a not in SAMPLER_WORDS)]  # the word first: tyro's order
        if from_recipe and words[-1] != f"sampler:{base.sampler.name}":
            base = TrainConfig(task=base.task)  # another sampler than the recipe's: the dataclass defaults
    if run.out is None and not wants_help:
        parser.error("the following arguments are required: --out")
    description = (
        "Train a value network (SEAGuL). Run options: --out DIR (required), --resume, --task NAME|MODULE:FACTORY, "
        f"--recipe NAME (of the task: {', '.join(recipe_names(base.task)) if run.task else 'default, paper, ...'}), "
        "--config FILE, --solver-options JSON. The flags below default to the starting config's values."
    )
    config = tyro.cli(
        TrainConfig,
        args=translated,
        default=base,
        prog="seagul train",
        description=description,
        config=(tyro.conf.CascadeSubcommandArgs,),
    )
    if run.solver_options is not None:
        config = config.replaced(solver_options=run.solver_options)
    return config, run


def config_flags(argv: Sequence[str]) -> Any:
    """The :class:`~seagul_learn.config.TrainConfig` of a ``seagul train`` command line (tests, scripts)."""
    return parse(argv)[0]


def main(argv: Sequence[str]) -> int:
    """Parse, train and print a summary; the last line is the run directory."""
    from seagul_learn.training import train

    config, run = parse(argv)
    result = train(config, run.out, resume=run.resume)
    last = result.metrics[-1]
    print(
        f"{task_label(config.task)} {config.sampler.name}: {result.num_solves} solves ({result.num_failures} failed), "
        f"{last.train_steps} training steps, validation mse_initial={last.mse_initial:.4g} "
        f"mse_all_knots={last.mse_all_knots:.4g}"
    )
    print(result.out_dir)
    return 0


def config_from_args(args: argparse.Namespace) -> Any:
    """The :class:`~seagul_learn.config.TrainConfig` of a namespace the ``seagul`` parser made for ``train`` (the
    run options and the remaining config flags, :func:`parse`)."""
    return parse(_argv_of(args))[0]


def run(args: argparse.Namespace) -> int:
    """Run from the ``seagul`` parser's namespace (the run options and the remaining flags)."""
    return main(_argv_of(args))


def _argv_of(args: argparse.Namespace) -> list[str]:
    argv: list[str] = []
    for action in run_parser()._actions:
        value = getattr(args, action.dest, None)
        if value is None or value is False:
            continue
        option = action.option_strings[0]
        if value is True:
            argv.append(option)
        elif action.dest == "solver_options":
            argv += [option, json.dumps(value)]
        elif action.dest == "task" and not isinstance(value, str):
            raise ValueError("a Task object cannot be passed through the parsed namespace; call main(argv)")
        else:
            argv += [option, str(value)]
    return [*argv, *getattr(args, "config_flags", [])]


COMMAND = Command(
    name="train",
    help="train a value network with adversarial (SEAGuL), closed-loop or uniform sampling",
    add_arguments=add_arguments,
    run=run,
    main=main,
)
