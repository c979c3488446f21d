"""Argument types and groups shared by ``seagul`` subcommands (each error names the problem and the accepted range)."""

from __future__ import annotations

import argparse
import math

from seagul_envs import Task, available_tasks, load_task

TASK_HELP = (
    "a task name ({names}) or module:factory, a function returning your Task (e.g. "
    "examples.custom_system:make_cartpole, or path/to/file.py:factory)"
)
"""Help of every ``--task`` option (``{names}`` is filled in)."""


def task_name(value: str) -> str:
    """A known task name; the error lists the available ones."""
    if value not in available_tasks():
        raise argparse.ArgumentTypeError(f"unknown task {value!r}; available tasks: {', '.join(available_tasks())}")
    return value


def task_argument(value: str) -> str | Task:
    """A ``--task`` value: a registered name (returned as the name) or ``module:factory`` / ``path/file.py:factory``
    (imported and called here, once; the Task object is returned and travels to the workers).

    The errors name the problem: an unknown name (listing the available ones), a module that does not import, a
    missing factory, a factory that raises or returns something that is not a Task, a malformed Task
    (:func:`seagul_envs.load_task`).
    """
    if ":" not in value:
        return task_name(value)
    try:
        return load_task(value)
    except (ValueError, TypeError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def positive_int(value: str) -> int:
    """An integer >= 1."""
    try:
        number = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value!r}") from None
    if number < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {number}")
    return number


def non_negative_int(value: str) -> int:
    """An integer >= 0."""
    try:
        number = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value!r}") from None
    if number < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {number}")
    return number


def non_negative_float(value: str) -> float:
    """A finite number >= 0."""
    try:
        number = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {value!r}") from None
    if not (math.isfinite(number) and number >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {value}")
    return number


def positive_float(value: str) -> float:
    """A finite number > 0."""
    number = non_negative_float(value)
    if number == 0:
        raise argparse.ArgumentTypeError("must be > 0, got 0")
    return number


def fraction(value: str) -> float:
    """A number in [0, 1]."""
    number = non_negative_float(value)
    if number > 1:
        raise argparse.ArgumentTypeError(f"must be in [0, 1], got {value}")
    return number


def add_task_argument(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """``--task NAME`` or ``--task module:factory`` (:func:`task_argument`)."""
    parser.add_argument(
        "--task",
        type=task_argument,
        required=required,
        metavar="NAME|MODULE:FACTORY",
        help=TASK_HELP.format(names=", ".join(available_tasks())),
    )


def add_parallel_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers N --backend local|ray`` (results never depend on them)."""
    parser.add_argument("--workers", type=positive_int, default=1, help="parallel solver processes (default 1)")
    parser.add_argument("--backend", choices=("local", "ray"), default="local", help="where solves run (default local)")
