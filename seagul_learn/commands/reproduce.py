"""``seagul reproduce``: the paper's experiment for one task end to end: the task's shipped controller in closed loop
beside LQR and the full-horizon MPC, then uniform, adversarial (SEAGuL) and closed-loop value-function learning at
an equal budget over paired seeds, closed-loop MPC statistics for every seed (grid and held-out starts), and a report
(see :mod:`seagul_learn.experiment`). ``--methods`` names other methods of the same pipeline, the task's own recipe
included: ``seagul reproduce acrobot --methods shipped uniform`` trains the shipped recipe (at its own budget) beside
the uniform sampler on the same schedule.

The configuration flags are derived by `tyro <https://brentyi.github.io/tyro/>`_ from
:class:`~seagul_learn.experiment.ExperimentConfig` (as ``seagul train``'s from ``TrainConfig``): one flag per field,
typed by its annotation and helped by its docstring (``--preset``, ``--seeds``, ``--workers`` (default 2 here),
``--backend``, ``--methods A B``, ``--sb3-models A.zip B.zip``, ``--sb3-algo``, ``--envs``, ``--ppo-model``,
``--progress/--no-progress``, ``--shipped-jit/--no-shipped-jit``), so a new field needs no edit here. The task is
the positional ``TASK`` (first, by convention: a name or ``module:factory``); ``--out DIR`` and ``--resume DIR`` are
not config fields.

**The spellings of earlier versions keep working**: :func:`translate_legacy` rewrites ``--ppo MODEL`` into
``--ppo-model MODEL`` and every ``--sb3 MODEL`` (repeatable, one path each, commas included) into the one
``--sb3-models`` list, in the order given, with a deprecation message on stderr naming the new spelling; the
comma-separated values of ``--methods``, ``--sb3-models`` and ``--envs`` (``--methods shipped,uniform``) are read as
the list they name.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from seagul_learn.cli import Command
from seagul_learn.commands._args import task_argument

CLI_WORKERS = 2
"""``--workers`` default of the command (the dataclass default is 1: one process for library callers)."""

RENAMED = {"--ppo": "--ppo-model", "--sb3": "--sb3-models"}
"""Option strings of earlier versions -> their tyro spelling (:func:`translate_legacy`)."""

LIST_FLAGS = ("--methods", "--sb3-models", "--envs")
"""The list-valued flags (several words; a single comma-separated word is the earlier spelling of the same list)."""

BOOL_FLAGS = ("--progress", "--no-progress", "--shipped-jit", "--no-shipped-jit", "-h", "--help")
"""The flags that take no value."""


def run_parser() -> argparse.ArgumentParser:
    """The options of ``seagul reproduce`` that are not config flags: the run directory and where to resume."""
    parser = argparse.ArgumentParser(prog="seagul reproduce", add_help=False)
    parser.add_argument("--out", default=None, help="run directory (default runs/<task>-<timestamp>)")
    parser.add_argument("--resume", metavar="DIR", default=None, help="finish an interrupted run in DIR")
    return parser


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``reproduce`` subparser of ``seagul --help`` (and of the docs check): ``TASK`` and the run options. The
    config flags are tyro's (``seagul reproduce --help`` prints them); :func:`main` parses the command line."""
    parser.add_argument(
        "task", metavar="TASK", help="acrobot, glider (or another registered name), or module:factory returning a Task"
    )
    for action in run_parser()._actions:
        parser._add_action(action)
    parser.add_argument(
        "config_flags", nargs=argparse.REMAINDER, help="ExperimentConfig flags (seagul reproduce --help)"
    )


# --------------------------------------------------------------------------------------------- the old flags
def _split_equals(argv: Sequence[str]) -> list[str]:
    """``--flag=value`` as ``--flag value`` (so that the flags below are recognised in either form)."""
    out: list[str] = []
    for arg in argv:
        head, eq, value = arg.partition("=")
        if eq and head.startswith("--"):
            out += [head, value]
        else:
            out.append(arg)
    return out


def translate_legacy(argv: Sequence[str]) -> tuple[list[str], list[str], str | None]:
    """``(argv for tyro, deprecation notes, the TASK word)`` of a ``seagul reproduce`` command line.

    Renamed flags (:data:`RENAMED`) become their tyro spelling with one ``"--old X -> --new X"`` note each; every
    ``--sb3 MODEL`` and ``--sb3-models`` value joins one ``--sb3-models`` list in the order given; a single
    comma-separated value of a list flag (:data:`LIST_FLAGS`) is split into its items. The ``TASK`` is the first word
    that no flag takes as its value (a list flag takes the words up to the next flag, or one comma-separated word).
    """
    args = _split_equals(argv)
    out: list[str] = []
    notes: list[str] = []
    models: list[str] = []
    models_at: int | None = None
    task: str | None = None
    i = 0
    while i < len(args):
        arg = args[i]
        flag = RENAMED.get(arg, arg)
        if arg in RENAMED and i + 1 < len(args):
            notes.append(f"{arg} {args[i + 1]} -> {flag} {args[i + 1]}")
        if not arg.startswith("-"):
            if task is None:
                task = arg
            else:
                out.append(arg)  # tyro names the stray word
            i += 1
            continue
        if arg in BOOL_FLAGS or i + 1 == len(args):
            out.append(arg)
            i += 1
            continue
        if flag in LIST_FLAGS:
            values: list[str] = []
            j = i + 1
            if arg == "--sb3":  # one path per occurrence, commas included
                values, j = [args[i + 1]], i + 2
            elif "," in args[i + 1]:  # the comma-separated spelling: one word
                values, j = [v.strip() for v in args[i + 1].split(",") if v.strip()], i + 2
            else:
                while j < len(args) and not args[j].startswith("-"):
                    values.append(args[j])
                    j += 1
            if flag == "--sb3-models":
                models += values
                if models_at is None:
                    models_at = len(out)
            else:
                out += [flag, *values]
            i = j
            continue
        out += [flag, args[i + 1]]
        i += 2
    if models_at is not None:
        out[models_at:models_at] = ["--sb3-models", *models]
    return out, notes, task


# ----------------------------------------------------------------------------------------------- the parse
def parse(argv: Sequence[str]) -> tuple[Any, argparse.Namespace]:
    """``(ExperimentConfig, run options)`` of a ``seagul reproduce`` command line (without the word ``reproduce``);
    the run options are ``out``, ``resume`` and ``task`` (the parsed ``TASK``: a name or the factory's Task).

    Raises:
        SystemExit: bad flags (status 2, tyro's or argparse's message naming the flag), a missing or unknown
            ``TASK`` (status 2), or ``--help`` (status 0).
    """
    import tyro

    from seagul_learn.experiment import ExperimentConfig

    parser = run_parser()
    run, rest = parser.parse_known_args(list(argv))
    translated, notes, word = translate_legacy(rest)
    if notes:
        print(
            "seagul reproduce: these flags are deprecated, read as their new spelling: " + "; ".join(notes),
            file=sys.stderr,
        )
    wants_help = any(a in ("-h", "--help") for a in translated)
    if word is None and not wants_help:
        parser.error("the following arguments are required: TASK")
    try:
        task = "acrobot" if word is None else task_argument(word)
    except argparse.ArgumentTypeError as exc:
        parser.error(f"argument TASK: {exc}")
    description = (
        "Run the paper's experiment for TASK (acrobot, glider, another registered name, or module:factory returning "
        "a Task) and write a report. Run options: --out DIR (default runs/<task>-<timestamp>), --resume DIR (finish "
        "an interrupted run in DIR). Flags of earlier versions (--ppo, --sb3 MODEL, comma-separated lists) still work."
    )
    config = tyro.cli(
        ExperimentConfig,
        args=translated,
        default=ExperimentConfig(task=task, workers=CLI_WORKERS),
        prog="seagul reproduce TASK",
        description=description,
    )
    _check_choices(parser, config)
    run.task = task
    return config, run


def _check_choices(parser: argparse.ArgumentParser, config: Any) -> None:
    """The flags whose values are names from a fixed list fail as argparse's choices did (status 2, naming the
    flag), before anything runs: ``--backend``, ``--sb3-algo`` and ``--methods`` (distinct known method names)."""
    from seagul_learn.experiment import METHOD_NAMES, SB3_ALGOS

    for flag, value, choices in (
        ("--backend", config.backend, ("local", "ray")),
        ("--sb3-algo", config.sb3_algo, SB3_ALGOS),
    ):
        if value not in choices:
            parser.error(f"argument {flag}: invalid choice: {value!r} (choose from {', '.join(choices)})")
    unknown = [m for m in config.methods if m not in METHOD_NAMES]
    if unknown:
        parser.error(f"argument --methods: unknown methods {unknown}; choose from {', '.join(METHOD_NAMES)}")
    if len(set(config.methods)) != len(config.methods):
        parser.error(f"argument --methods: a method is named twice: {' '.join(config.methods)}")


def config_flags(argv: Sequence[str]) -> Any:
    """The :class:`~seagul_learn.experiment.ExperimentConfig` of a ``seagul reproduce`` command line (tests,
    scripts)."""
    return parse(argv)[0]


def main(argv: Sequence[str]) -> int:
    """Parse, then run (or resume) the experiment; the last line printed is the path of ``report.md``."""
    from seagul_envs import Task
    from seagul_envs.tasks import task_label
    from seagul_learn.experiment import Experiment

    config, run = parse(argv)
    if run.resume is not None:
        if run.out is not None and Path(run.out) != Path(run.resume):
            raise ValueError("give either --out (a new run) or --resume DIR (an interrupted one), not both")
        given = run.task if isinstance(run.task, Task) else None
        experiment = Experiment.resume(Path(run.resume), workers=config.workers, progress=config.progress, task=given)
        if task_label(experiment.config.task) != task_label(run.task):
            raise ValueError(
                f"{run.resume!r} is a {task_label(experiment.config.task)} run, not {task_label(run.task)}"
            )
    else:
        experiment = Experiment.create(config, None if run.out is None else Path(run.out))
    shown = "<the same module:factory>" if isinstance(run.task, Task) else run.task
    print(f"run directory: {experiment.out} (resume with: seagul reproduce {shown} --resume {experiment.out})")
    report = experiment.run()
    print(report)
    return 0


def run(args: argparse.Namespace) -> int:
    """Run from the ``seagul`` parser's namespace (``TASK``, the run options and the remaining flags)."""
    argv = [args.task]
    for name in ("out", "resume"):
        if getattr(args, name, None) is not None:
            argv += [f"--{name}", str(getattr(args, name))]
    return main([*argv, *getattr(args, "config_flags", [])])


COMMAND = Command(
    name="reproduce",
    help="run the paper's experiment for a task (the shipped controller, then uniform vs SEAGuL vs closed-loop "
    "learning, or the --methods named, e.g. the shipped recipe, at an equal budget with per-seed MPC evaluation) and "
    "write a report",
    add_arguments=add_arguments,
    run=run,
    main=main,
)
