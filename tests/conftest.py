"""Test-session settings shared by every test file."""

from __future__ import annotations

import pytest

#: Files that take minutes, run first: with ``--dist loadfile`` (scripts/test.sh) a file runs on one worker, and a
#: long file handed out last would leave the other worker idle at the end.
LONG_FILES = ("tests/test_experiment.py",)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in LONG_FILES)  # stable: the rest keep their order
