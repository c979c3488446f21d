"""``benchmarks/_common.parse_seeds``: the seed lists of the benchmarks' command lines."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._common import parse_seeds


def test_ranges_lists_and_mixes_keep_their_order() -> None:
    assert parse_seeds("0-4") == [0, 1, 2, 3, 4]
    assert parse_seeds("7,3, 5") == [7, 3, 5]
    assert parse_seeds("0-2,10") == [0, 1, 2, 10]


@pytest.mark.parametrize("text", ["a", "5-2", "", "1-2-3", ",", "0-x"])
def test_what_it_cannot_read_is_named(text: str) -> None:
    with pytest.raises(ValueError, match="seeds: "):
        parse_seeds(text)
