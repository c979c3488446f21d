"""Same seed and configuration -> identical datasets and network weights, whatever the number of workers.

On the REAL trajectory optimizer (the toy-solver version lives in tests/test_training.py):
``train`` with ``workers=1`` (solves in this process) and ``workers=2`` (a loky process pool, two solves per
chunk) must store bit-identical records and end with bit-identical weights. Only wall-clock times may differ.
``solve_many`` with 1 and 2 workers on every task is the conformance battery's (tests/test_conformance.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from seagul_learn.training import TrainConfig, TrainResult, train

_WALL_CLOCK = {"solve_time", "wall_time"}


def _train(tmp_path: Path, workers: int) -> TrainResult:
    config = TrainConfig(
        task="acrobot",
        sampler="adversarial",  # the network steers the next starts: any drift would compound
        budget=6,
        solves_per_round=3,
        train_steps_per_round=20,
        batch_size=32,
        pretrain_solves=3,
        pretrain_steps=10,
        adv_max_steps=3,
        sobolev_weight=0.5,  # the per-knot dual gradients enter the loss too
        seed=5,
        validate=False,
        workers=workers,
        progress=False,
    )
    return train(config, tmp_path / f"workers{workers}")


# A minute on a cold solver cache (the acrobot's compiled solvers, three training rounds twice). Covered in the default
# suite by tests/test_training.py (a run with workers=2 equals the run with 1, on the toy solver) and
# tests/test_conformance.py (solve_many bit-identical for 1 and 2 workers on the real optimizer, every task).
@pytest.mark.slow
def test_training_is_identical_for_one_and_two_workers(tmp_path: Path) -> None:
    one, two = _train(tmp_path, 1), _train(tmp_path, 2)
    recs_one, recs_two = one.dataset.records(), two.dataset.records()
    assert len(recs_one) == len(recs_two) == 3 + 6
    assert any(r.step > 0 for r in recs_one)  # ascent iterates: starts that depend on the network
    for r1, r2 in zip(recs_one, recs_two, strict=True):
        a1, a2 = r1.to_arrays(), r2.to_arrays()
        for key in a1.keys() - _WALL_CLOCK:
            np.testing.assert_array_equal(a1[key], a2[key], err_msg=f"record {r1.index}: {key}")
    np.testing.assert_array_equal(one.network.casadi_parameters(), two.network.casadi_parameters())
    for m1, m2 in zip(one.metrics, two.metrics, strict=True):
        assert (m1.solves, m1.train_steps, m1.failures) == (m2.solves, m2.train_steps, m2.failures)
