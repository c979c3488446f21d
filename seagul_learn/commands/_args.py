"""Argument types and groups shared by ``seagul`` subcommands (each error names the problem and the accepted range)."""

from __future__ import annotations

import argparse
import math

from seagul_envs import available_tasks


def task_name(value: str) -> str:
    """A known task name; the error lists the available ones."""
    if value not in available_tasks():
        raise argparse.ArgumentTypeError(f"unknown task {value!r}; available tasks: {', '.join(available_tasks())}")
    return value


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
    """``--task NAME``."""
    parser.add_argument("--task", type=task_name, required=required, help=f"task name ({', '.join(available_tasks())})")


def add_parallel_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers N --backend local|ray`` (results never depend on them)."""
    parser.add_argument("--workers", type=positive_int, default=1, help="parallel solver processes (default 1)")
    parser.add_argument("--backend", choices=("local", "ray"), default="local", help="where solves run (default local)")
