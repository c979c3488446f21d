"""Assertions on trajectory-optimization results shared by the tests (imported as ``result_checks``, like
``toy_problem``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from seagul_learn.results import SolveResult


def assert_same_results(a: list[SolveResult], b: list[SolveResult]) -> None:
    """Every field of every result equal bit for bit (NaNs equal), the wall-clock ``solve_time`` excepted."""
    assert len(a) == len(b)
    for i, (ra, rb) in enumerate(zip(a, b, strict=True)):
        for f in dataclasses.fields(SolveResult):
            if f.name == "solve_time":
                continue
            va, vb = getattr(ra, f.name), getattr(rb, f.name)
            if isinstance(va, np.ndarray | float):
                np.testing.assert_array_equal(va, vb, err_msg=f"result {i}: {f.name}")
            else:
                assert va == vb, f"result {i}: {f.name}: {va!r} != {vb!r}"
