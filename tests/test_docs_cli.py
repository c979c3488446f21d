"""The command-line reference (docs/reference/cli.md) names every option ``seagul <command> --help`` prints.

The page's option tables are written by hand; this test keeps them from drifting: every long option (``--name``) of
every subcommand and of ``seagul`` itself that ``--help`` shows must appear on the page in backticks, and every
subcommand must have its own section. It reads the parsers in-process (``seagul_learn.cli.build_parser``), so it
runs in well under a second.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from seagul_learn.cli import build_parser

PAGE = Path(__file__).resolve().parents[1] / "docs" / "reference" / "cli.md"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _documented(option: str, text: str) -> bool:
    """``option`` opens a code span of ``text`` as a whole word: ``--sb3`` in `` `--sb3 MODEL` ``, not in
    `` `--sb3-algo` ``."""
    return re.search(rf"`{re.escape(option)}(?![\w-])", text) is not None


def _printed_long_options(parser: argparse.ArgumentParser) -> set[str]:
    """The ``--long`` option strings that ``parser.format_help()`` shows (hidden aliases left out)."""
    return {
        option
        for action in parser._actions
        if action.help != argparse.SUPPRESS
        for option in action.option_strings
        if option.startswith("--")
    }


COMMANDS = _subparsers(build_parser())


def test_every_command_is_found():
    assert {"evaluate", "generate", "reproduce", "train"} <= set(COMMANDS)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_option_of_the_command_is_documented(name):
    text = PAGE.read_text()
    assert re.search(rf"^## `seagul {name}`", text, re.MULTILINE), f"no section '## `seagul {name}`' in {PAGE.name}"
    missing = sorted(o for o in _printed_long_options(COMMANDS[name]) if not _documented(o, text))
    assert not missing, f"seagul {name}: options missing from {PAGE.name}: {missing}"


def test_the_top_level_options_are_documented():
    text = PAGE.read_text()
    missing = sorted(o for o in _printed_long_options(build_parser()) if not _documented(o, text))
    assert not missing, f"seagul: options missing from {PAGE.name}: {missing}"


def test_the_check_reads_what_help_prints():
    """The option strings the test compares are the ones in the help text (no option is hidden from it)."""
    for name, parser in COMMANDS.items():
        shown = parser.format_help()
        for option in _printed_long_options(parser):
            assert option in shown, f"seagul {name} --help does not print {option}"
