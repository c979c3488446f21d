"""The ``seagul`` command line: one subcommand per module in :mod:`seagul_learn.commands`.

Adding a subcommand (e.g. ``evaluate``, ``reproduce``) takes one new file and no edit here: create
``seagul_learn/commands/<name>.py`` defining ::

    COMMAND = Command(
        name="evaluate",
        help="one line shown by `seagul --help`",
        add_arguments=add_arguments,   # (argparse.ArgumentParser) -> None
        run=run,                       # (argparse.Namespace) -> int exit code
    )

Modules are discovered in alphabetical order (files starting with ``_`` are helpers, e.g.
:mod:`seagul_learn.commands._args` has the shared argument types: task names that list the available ones, positive
integers, the ``--workers``/``--backend`` pair). A command whose flags another parser derives gives its ``Command`` a
``main`` that takes its own words: ``train`` and ``reproduce`` parse them with tyro from their config dataclasses
(``TrainConfig``: ``--sampler.episodes 20``; ``ExperimentConfig``), and their ``seagul`` subparsers only list the run
options. Argument errors exit with status 2 and a message naming the argument; a
``ValueError``/``FileExistsError``/``FileNotFoundError`` raised by a command is reported as
``seagul <command>: error: <message>`` (status 2) without a traceback; Ctrl-C exits with status 130.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import seagul_learn.commands
from seagul_learn import __version__


@dataclass(frozen=True)
class Command:
    """A ``seagul`` subcommand."""

    name: str
    """The word after ``seagul``."""
    help: str
    """One line for ``seagul --help``."""
    add_arguments: Callable[[argparse.ArgumentParser], None]
    """Declares the subcommand's arguments."""
    run: Callable[[argparse.Namespace], int]
    """Runs it; returns the exit code."""
    main: Callable[[Sequence[str]], int] | None = None
    """Parses its own command line (the words after its name) and runs it, instead of the ``seagul`` parser: a
    command whose flags another parser derives (``train``: tyro, from the config dataclasses). Its subparser then
    only lists its run options for ``seagul --help``."""


def discover_commands() -> list[Command]:
    """Every ``COMMAND`` defined by a public module of :mod:`seagul_learn.commands`, by module name."""
    commands: list[Command] = []
    package = seagul_learn.commands
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        command = getattr(module, "COMMAND", None)
        if isinstance(command, Command):
            commands.append(command)
    return commands


def build_parser(commands: Sequence[Command] | None = None) -> argparse.ArgumentParser:
    """The top-level parser with one subparser per command."""
    parser = argparse.ArgumentParser(
        prog="seagul",
        description="Learn value functions from trajectory optimization with adversarial sampling (SEAGuL).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in commands if commands is not None else discover_commands():
        p = sub.add_parser(command.name, help=command.help, description=command.help)
        command.add_arguments(p)
        p.set_defaults(_run=command.run, _name=command.name)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``seagul`` console script."""
    words = list(sys.argv[1:] if argv is None else argv)
    commands = discover_commands()
    own = {c.name: c.main for c in commands if c.main is not None}
    if words and words[0] in own:
        name, command_main = words[0], own[words[0]]
        return _guarded(name, lambda: command_main(words[1:]))
    parser = build_parser(commands)
    args = parser.parse_args(words)
    return _guarded(args._name, lambda: args._run(args))


def _guarded(name: str, run: Callable[[], int]) -> int:
    """``run()``'s exit code; the errors a user can fix are a message and status 2, Ctrl-C status 130."""
    try:
        return int(run() or 0)
    except (ValueError, FileExistsError, FileNotFoundError) as exc:
        print(f"seagul {name}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\nseagul {name}: interrupted (rerun with --resume to continue where it stopped)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    # Under ``python -m`` this file is ``__main__``; the commands register against ``seagul_learn.cli.Command``.
    from seagul_learn.cli import main as _main

    sys.exit(_main())
